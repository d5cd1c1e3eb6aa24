"""Editing a running world: the pieces :class:`~cgp_core.world.World`'s spawn / delete / teleport / query
methods are made of (no ROS here; the node maps ROS 2's ``simulation_interfaces`` onto those methods).

- A world's bodies are a static :class:`~cgp_core.bodies.BodyModel` and a :class:`~cgp_core.bodies.BodyState`
  (structure of arrays, indexed by body).  Spawning or deleting never edits them in place: it builds a *new*
  model (and state) with the arrays concatenated (:func:`concatenate_bodies`) or selected
  (:func:`select_bodies`), so everything that caches per model (collision primitives, warm starts) sees a new
  identity and rebuilds.  Bodies keep their relative order; a spawned body comes last.
- :class:`EditError`: why an edit was refused, with a ``kind`` a caller maps onto its result codes.  A refused
  edit changes nothing.
- :class:`EntityState`: what a query returns for a body or a flock.
- :func:`name_filter`: a POSIX extended regular expression (the ``simulation_interfaces`` filter syntax),
  matched in linear time (RE2).
- :func:`body_distances`: signed distance from a point to every body's surface (overlap queries).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .bodies import BodyModel, BodyState, Shape
from .geometry import box_distance, capsule_distance, sphere_distance
from .limits import MAX_COORDINATE, MAX_PATTERN_LENGTH
from .rotation import quat_to_matrix

__all__ = ["EditError", "EntityState", "WORLD_FRAMES", "concatenate_bodies", "select_bodies", "name_filter",
           "body_distances", "check_pose", "check_vector"]


class EditError(ValueError):
    """A world edit that was refused (nothing changed).  ``kind``:

    ``unknown``       no body, flock or robot of that name;
    ``name_taken``    the name is already a body's or a flock's;
    ``name_invalid``  not a usable name (see :data:`cgp_core.scene.ROS_SAFE_NAME`);
    ``invalid_pose``  a pose / twist that is not finite, a zero quaternion, a frame other than the world's;
    ``not_possible``  the request is well-formed but cannot be done (a twist for a fixed body, the world's body
                      limit, a flock moved out of its bounds...).
    """

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind


@dataclass
class EntityState:
    """A body's or a flock's state, world frame.

    kind:                 "body" | "flock".
    position:             (3,) m — a body's centre of mass; a flock's centroid.
    orientation:          (4,) xyzw — a body's orientation; the identity for a flock.
    linear_velocity:      (3,) m/s — of the COM; a flock's mean boid velocity.
    angular_velocity:     (3,) rad/s, world axes; zero for a flock.
    linear_acceleration:  (3,) m/s² — over the last tick (Δv / dt); zero before the first tick.
    angular_acceleration: (3,) rad/s² — Δω / dt over the last tick; zero for a flock.
    """

    kind: str
    position: np.ndarray
    orientation: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray
    linear_acceleration: np.ndarray
    angular_acceleration: np.ndarray


# ---- new model / state objects -----------------------------------------------------------------------------


def _per_body(value, n: int) -> bool:
    return (isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[0] == n) or \
        (isinstance(value, list) and len(value) == n)


def _join(a, b):
    if isinstance(a, list) or isinstance(b, list):
        return list(a) + list(b)
    return np.concatenate((a, b))


def concatenate_bodies(model_a: BodyModel, state_a: BodyState, model_b: BodyModel,
                       state_b: BodyState) -> tuple[BodyModel, BodyState]:
    """New model and state: the bodies of ``a`` followed by those of ``b``.  Every per-body field (an array
    whose first axis is the body, or a list of one item per body) is joined, so fields added to the
    dataclasses later are carried along."""
    model = BodyModel(**{f.name: _join(getattr(model_a, f.name), getattr(model_b, f.name))
                         for f in fields(BodyModel)})
    rotation_a, rotation_b = state_a.rotation, state_b.rotation
    if (rotation_a is None) != (rotation_b is None):  # an integrator that keeps R: give every body one
        rotation_a, rotation_b = state_a.rotation_matrices(), state_b.rotation_matrices()
    values = {}
    for f in fields(BodyState):
        if f.name == "rotation":
            values[f.name] = None if rotation_a is None else np.concatenate((rotation_a, rotation_b))
        else:
            values[f.name] = _join(getattr(state_a, f.name), getattr(state_b, f.name))
    return model, BodyState(**values)


def select_bodies(model: BodyModel, state: BodyState, keep: np.ndarray) -> tuple[BodyModel, BodyState]:
    """New model and state holding the bodies ``keep`` (an index array, in the order given)."""
    n = model.count
    keep = np.asarray(keep, dtype=np.intp)

    def take(value):
        if value is None or not _per_body(value, n):
            return value
        return [value[i] for i in keep] if isinstance(value, list) else value[keep]

    return (BodyModel(**{f.name: take(getattr(model, f.name)) for f in fields(BodyModel)}),
            BodyState(**{f.name: take(getattr(state, f.name)) for f in fields(BodyState)}))


# ---- checks ---------------------------------------------------------------------------------------------------

WORLD_FRAMES = ("", "world")


def check_pose(position, orientation, what: str = "pose") -> tuple[np.ndarray, np.ndarray]:
    """Finite position (3,) and a finite, non-zero quaternion (4,) xyzw, returned normalized (as scenes
    normalize theirs); :class:`EditError` ``invalid_pose`` otherwise."""
    p = np.asarray(position, dtype=float).reshape(3)
    q = np.asarray(orientation, dtype=float).reshape(4)
    if not np.isfinite(p).all():
        raise EditError("invalid_pose", f"{what}.position must be finite, got {p.tolist()}")
    if not (np.abs(p) <= MAX_COORDINATE).all():
        raise EditError("invalid_pose", f"{what}.position must be within ±{MAX_COORDINATE:g} m on every axis (what "
                        f"cgp_sim simulates: cgp_core.limits), got {p.tolist()}")
    if not np.isfinite(q).all():
        raise EditError("invalid_pose", f"{what}.orientation must be finite, got {q.tolist()}")
    scale = float(np.abs(q).max())
    if scale > 1.0:  # |q| of huge components would overflow to inf (and q / inf is a zero quaternion)
        q = q / scale
    norm = float(np.linalg.norm(q))
    if norm < 1e-9:
        raise EditError("invalid_pose", f"{what}.orientation is a zero quaternion (x, y, z, w); the identity is "
                        "(0, 0, 0, 1)")
    return p, q / norm


def check_vector(value, what: str, max_norm: float | None = None, unit: str = "") -> np.ndarray:
    """A finite (3,) vector, of magnitude at most ``max_norm`` if given; :class:`EditError` ``invalid_pose``."""
    v = np.asarray(value, dtype=float).reshape(3)
    if not np.isfinite(v).all():
        raise EditError("invalid_pose", f"{what} must be finite, got {v.tolist()}")
    if max_norm is not None:
        scale = float(np.abs(v).max())
        norm = scale * float(np.linalg.norm(v / scale)) if scale > 0.0 else 0.0  # no overflow to inf
        if not norm <= max_norm:
            raise EditError("invalid_pose", f"{what}: its magnitude must be at most {max_norm:g} {unit} (what cgp_sim "
                            f"simulates: cgp_core.limits), got {norm:g}")
    return v


# ---- queries ------------------------------------------------------------------------------------------------

def _re2_options():
    import re2

    options = re2.Options()
    options.posix_syntax = True  # POSIX egrep syntax: no Perl classes (\d), no (?flags), no \b
    options.longest_match = True  # POSIX's leftmost-longest (which match is found; not whether one is)
    options.log_errors = False  # the error goes into the reply, not onto stderr
    return options


def name_filter(pattern: str):
    r"""A POSIX extended regular expression (``simulation_interfaces/msg/EntityFilters``: a name matches when
    the expression matches anywhere in it, as ``regexec`` does), compiled with RE2 (google-re2), which matches
    in time linear in the name whatever the pattern: a pattern such as ``(a+)+$`` cannot stall the node (with
    Python's backtracking ``re`` it took 16.8 s against a 27-character name, doubling per character).

    Supported, exactly: RE2 in POSIX syntax mode — ERE's ``. [] [^] ^ $ ( ) | * + ? {m,n}`` and bracket classes
    (``[[:digit:]]``, ``[[:alpha:]]``...), repetition counts up to 1000; not supported (refused, naming the
    problem): back-references (not ERE either), Perl classes (``\d``, ``\w``), ``(?i)`` flags, and patterns
    longer than :data:`~cgp_core.limits.MAX_PATTERN_LENGTH` characters or whose compiled program exceeds RE2's
    8 MB.  Returns an object with ``search(name)``; ``ValueError`` naming the problem for an invalid one."""
    import re2

    if len(pattern) > MAX_PATTERN_LENGTH:
        raise ValueError(f"a regular expression of {len(pattern)} characters; at most {MAX_PATTERN_LENGTH}")
    try:
        return re2.compile(pattern, _re2_options())
    except re2.error as exc:
        reason = exc.args[0].decode("utf-8", "replace") if exc.args and isinstance(exc.args[0], bytes) else str(exc)
        shown = pattern if len(pattern) <= 80 else pattern[:80] + "..."
        raise ValueError(f"invalid regular expression {shown!r} (POSIX extended syntax, as RE2 reads it): "
                         f"{reason}") from None


def body_distances(model: BodyModel, state: BodyState, point) -> np.ndarray:
    """(n,) signed distance [m] from ``point`` (3,) to every body's surface (negative inside), with the
    point-vs-shape distances of :mod:`cgp_core.geometry` (one vectorized call per shape kind)."""
    p = np.asarray(point, dtype=float).reshape(1, 3)
    out = np.empty(model.count)
    if model.count == 0:
        return out
    shape = np.asarray(model.shape)
    R = quat_to_matrix(state.orientation)
    spheres = np.flatnonzero(shape == Shape.SPHERE)
    out[spheres] = sphere_distance(p, state.position[spheres], model.radius[spheres])[0][0]
    boxes = np.flatnonzero(shape == Shape.BOX)
    out[boxes] = box_distance(p, state.position[boxes], R[boxes], model.half_extents[boxes])[0][0]
    capsules = np.flatnonzero(shape == Shape.CAPSULE)
    out[capsules] = capsule_distance(p, state.position[capsules], R[capsules, :, 2],
                                     model.half_extents[capsules, 2], model.radius[capsules])[0][0]
    for i in np.flatnonzero(shape == Shape.PARTICLES):  # a particle set: its nearest particle's sphere
        centers = state.position[i] + np.asarray(model.particles[i])[:, :3] @ R[i].T
        out[i] = sphere_distance(p, centers, np.full(len(centers), model.radius[i]))[0].min()
    for i in np.flatnonzero(shape == Shape.CONVEX):
        out[i] = _hull_distance(p[0], model.hulls[i], state.position[i], R[i])
    for i in np.flatnonzero(shape == Shape.COMPOUND):  # its nearest part
        out[i] = _parts_distance(p, model.parts[i], state.position[i], R[i])
    for i in np.flatnonzero(shape == Shape.MESH):  # a surface: the distance to its closest point (no inside)
        from .collision.bvh import bvh_closest_point

        mesh = model.meshes[i]
        local = (p[0] - state.position[i]) @ R[i]
        out[i] = bvh_closest_point(tuple(mesh.arrays), local, np.inf)[1]
    return out


def _hull_distance(point: np.ndarray, hull, position: np.ndarray, rotation: np.ndarray) -> float:
    """Signed distance from a point to a posed convex hull: GJK (EPA inside), exact."""
    from .collision.epa import penetration

    core = np.zeros((1, 3))
    return float(penetration(hull.vertices, hull.adjacency_start, hull.adjacency, np.asarray(position, float),
                             np.ascontiguousarray(rotation, dtype=float), 0.0, core, np.zeros(2, np.int64),
                             np.zeros(0, np.int64), np.asarray(point, float), np.eye(3), 0.0)[0])


def _parts_distance(p: np.ndarray, parts, position: np.ndarray, rotation: np.ndarray) -> float:
    """Signed distance from ``p (1, 3)`` to a compound body's nearest part."""
    centres = position + parts.position @ rotation.T
    turned = rotation @ parts.rotation
    best = np.inf
    for k in range(parts.count):
        kind = int(parts.shape[k])
        if kind == Shape.SPHERE:
            d = sphere_distance(p, centres[k:k + 1], parts.radius[k:k + 1])[0][0, 0]
        elif kind == Shape.BOX:
            d = box_distance(p, centres[k:k + 1], turned[k:k + 1], parts.half_extents[k:k + 1])[0][0, 0]
        elif kind == Shape.CAPSULE:
            d = capsule_distance(p, centres[k:k + 1], turned[k:k + 1, :, 2], parts.half_extents[k:k + 1, 2],
                                 parts.radius[k:k + 1])[0][0, 0]
        else:
            d = _hull_distance(p[0], parts.hulls[k], centres[k], turned[k])
        best = min(best, float(d))
    return best

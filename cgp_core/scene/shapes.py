"""Issue 25's shapes: convex hulls (of ``points`` or of a mesh file's vertices), compound bodies (parts at
relative poses) and static meshes (a BVH over a mesh file's triangles); the mesh files they read are
:mod:`.mesh_files`'."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ..bodies import CompoundParts, Shape
from ..inertia import compound_mass_properties, shape_mass_properties
from ..limits import MAX_PARTS_PER_BODY
from ..rotation import quat_normalize
from .mesh_files import cached, parse_scale, read_mesh, scaled_points_problem
from .specs import PART_KEYS, PART_SHAPES, SHAPE_KEYS, BodySpec
from .validation import COORDINATES, LENGTHS, Validator, kind_of


def parse_issue25_shape(v: Validator, raw: dict, key: str, shape_name: str, spec: BodySpec, mass, density) -> None:
    """``shape: convex | compound | mesh`` (keys checked by the caller): fills ``spec``'s shape, mass properties
    (exact for the polyhedron, :mod:`cgp_core.inertia`), ``half_extents`` (a box about the COM that holds the
    shape) and ``position`` (the COM in the scene's body coordinates, turned into the world by the caller)."""
    if shape_name == "convex":
        hull = _convex_hull_of(v, raw, key, spec.name, spec.notes)
        if hull is None:
            return
        from ..collision.convex import centred_hull

        try:
            centred, spec.mass, com, spec.inertia_body = centred_hull(hull, mass=mass, density=density,
                                                                      what=f"{key}.points")
        except ValueError as exc:
            v.fail("", str(exc))
            return
        spec.hull = centred
        spec.position = com
        spec.half_extents = np.abs(centred.vertices).max(axis=0)
    elif shape_name == "compound":
        _parse_compound(v, raw.get("parts"), f"{key}.parts", spec, mass, density)
    else:
        mesh = _static_mesh(v, raw, key, spec.notes, spec.name)
        if mesh is None:
            return
        spec.mesh = mesh
        spec.two_sided = v.boolean(raw.get("two_sided", False), f"{key}.two_sided")
        spec.mass, spec.inertia_body = 0.0, np.eye(3)  # fixed: never used
        spec.half_extents = np.abs(mesh.vertices).max(axis=0)


def _convex_hull_of(v: Validator, raw: dict, key: str, name: str, notes: list):
    """The :class:`~cgp_core.collision.convex.ConvexPolyhedron` of a convex body or part: of ``points`` or of the
    vertices of ``mesh`` (exactly one), scaled; a non-convex input gives its hull and a note says so.

    A mesh file's hull is built once per file (cached with the file, :mod:`.mesh_files`) from its vertices as
    read, and the scaled hull is the hull of its vertices scaled (a scale is linear: the hull of the scaled
    points is the scaled hull), which costs a few hundred points, not the file's (a compound body's parts may
    name one file at many scales)."""
    from ..collision.convex import MAX_INPUT_POINTS, HullError, convex_hull

    if ("points" in raw) == ("mesh" in raw):
        v.fail(key, "give points (a list of [x, y, z]) or mesh (an .stl / .obj file): exactly one")
        return None
    try:
        if "mesh" in raw:
            loaded = read_mesh(v, raw, key, solid=True)
            if loaded is None:
                return None
            what = f"{key}.mesh ({loaded.path.name})"
            given = f"{len(loaded.vertices)} vertices of {loaded.path.name}"
            unscaled = cached(("hull", loaded.identity), lambda: convex_hull(loaded.file_vertices, what=_WHAT))
            hull = unscaled
            if loaded.scale != (1.0, 1.0, 1.0):
                scaled = convex_hull(unscaled.vertices * loaded.scale, what=_WHAT)
                hull = replace(scaled, interior_points=len(loaded.vertices) - len(scaled.vertices))
        else:
            scale = parse_scale(v, raw, key)
            points = raw["points"]
            if not isinstance(points, list):
                v.fail(f"{key}.points", f"must be a list of [x, y, z] points, got {kind_of(points)}")
                return None
            if len(points) > MAX_INPUT_POINTS:
                v.fail(f"{key}.points", f"{len(points)} points; at most {MAX_INPUT_POINTS}")
                return None
            before = len(v.problems)
            rows = [v.vector(p, f"{key}.points[{i}]", 3, within=COORDINATES, unit="m") for i, p in enumerate(points)]
            if len(v.problems) > before or scale is None:
                return None
            points = np.array(rows, dtype=float).reshape(-1, 3) * scale
            what, given = f"{key}.points", f"{len(points)} points"
            problem = scaled_points_problem(points, solid=True)
            if problem:
                v.fail(f"{key}.scale" if "scale" in raw else f"{key}.points", problem)
                return None
            hull = convex_hull(points, what=what)
    except HullError as exc:
        v.fail("", str(exc).replace(_WHAT, what, 1))
        return None
    if hull.interior_points:
        notes.append(("warn", f"{v.source}: {key}: {hull.interior_points} of the {given} are not vertices of their "
                              f"convex hull (inside it, on a face or edge, or repeated): body {name} is the hull, "
                              f"{len(hull.vertices)} vertices"))
    return hull


#: what a cached hull's refusal names, replaced by the key path of the request that meets it
_WHAT = "<mesh>"


def _static_mesh(v: Validator, raw: dict, key: str, notes: list, name: str):
    """A fixed body's :class:`~cgp_core.collision.bvh.StaticMesh` (its BVH built once per file and scale, cached),
    and a note with the build time and memory."""
    from ..collision.bvh import StaticMesh

    if "mesh" not in raw:
        v.fail(f"{key}.mesh", "missing (an .stl / .obj file)")
        return None
    loaded = read_mesh(v, raw, key, solid=False)
    if loaded is None:
        return None
    mesh = cached(("bvh", loaded.identity, loaded.scale), lambda: StaticMesh.build(loaded.vertices,
                                                                                   loaded.triangles))
    notes.append(("info", f"static mesh {name}: {loaded.path.name}, {len(mesh.triangles)} triangles, "
                          f"{len(mesh.vertices)} vertices; BVH of {len(mesh.node_count)} nodes built in "
                          f"{mesh.build_seconds * 1e3:.1f} ms, {mesh.nbytes / 1e6:.2f} MB with the mesh"))
    return mesh


def _parse_compound(v: Validator, raw: Any, key: str, spec: BodySpec, mass, density) -> None:
    """A compound body: each part's volume and inertia per unit density (closed forms, or exact for a convex
    part), the body's density (``density``, or ``mass`` over the parts' total volume), and the lecture's
    J = Σ Jᵢ over the parts by the parallel-axis theorem (:func:`cgp_core.inertia.compound_mass_properties`).
    Parts are summed as given: where two overlap, the overlap counts twice."""
    from ..collision.convex import centred_hull
    from ..rotation import quat_to_matrix

    if not isinstance(raw, list) or not raw:
        v.fail(key, f"must be a non-empty list of parts ({{shape: sphere | box | capsule | convex, <its size "
                    f"keys>, position, orientation}}), got {kind_of(raw)}")
        return
    if len(raw) > MAX_PARTS_PER_BODY:
        v.fail(key, f"{len(raw)} parts; at most {MAX_PARTS_PER_BODY}")
        return
    before = len(v.problems)
    shapes, positions, rotations, radii, halves, hulls, volumes, inertias = [], [], [], [], [], [], [], []
    for i, part in enumerate(raw):
        where = f"{key}[{i}]"
        if not isinstance(part, dict):
            v.fail(where, f"must be a mapping, got {kind_of(part)}")
            continue
        v.no_unknown_keys(part, PART_KEYS, where)
        if "shape" not in part:
            v.fail(f"{where}.shape", f"missing (one of {', '.join(PART_SHAPES)})")
            continue
        shape_name = v.choice(part["shape"], f"{where}.shape", list(PART_SHAPES), "sphere")
        for other in PART_SHAPES:
            for k in SHAPE_KEYS[other] - SHAPE_KEYS[shape_name]:
                if k in part:
                    v.fail(f"{where}.{k}", f"does not apply to shape {shape_name} (it is for {other})")
        position = v.vector(part.get("position", [0, 0, 0]), f"{where}.position", 3, within=COORDINATES, unit="m")
        q = v.vector(part.get("orientation", [0, 0, 0, 1]), f"{where}.orientation", 4,
                     default=np.array([0, 0, 0, 1.0]))
        if np.linalg.norm(q) < 1e-9:
            v.fail(f"{where}.orientation", "zero quaternion (x, y, z, w); identity is [0, 0, 0, 1]")
            continue
        R = quat_to_matrix(quat_normalize(q)[None])[0]
        radius, half, hull = 0.0, np.zeros(3), None
        part_before = len(v.problems)
        try:
            if shape_name == "convex":
                found = _convex_hull_of(v, part, where, spec.name, spec.notes)
                if found is None:
                    continue
                hull, volume, com, inertia = centred_hull(found, density=1.0, what=f"{where}.points")
                position = position + R @ com  # the part's centre is its COM
            elif shape_name == "box":
                if "size" not in part:
                    v.fail(f"{where}.size", "missing (full extents [x, y, z])")
                    continue
                size = v.vector(part["size"], f"{where}.size", 3, minimum=0.0, exclusive_min=True,
                                default=np.ones(3), within=LENGTHS, unit="m")
                half = 0.5 * size
                volume, inertia = shape_mass_properties("box", size=size, density=1.0)
            else:
                if "radius" not in part:
                    v.fail(f"{where}.radius", "missing")
                    continue
                radius = v.number(part["radius"], f"{where}.radius", minimum=0.0, exclusive_min=True, default=0.1,
                                  within=LENGTHS, unit="m")
                if shape_name == "capsule":
                    if "length" not in part:
                        v.fail(f"{where}.length", "missing (length of the axis segment, without the caps)")
                        continue
                    half[2] = 0.5 * v.number(part["length"], f"{where}.length", minimum=0.0, exclusive_min=True,
                                             default=1.0, within=LENGTHS, unit="m")
                    volume, inertia = shape_mass_properties("capsule", radius=radius, half_length=half[2],
                                                            density=1.0)
                else:
                    volume, inertia = shape_mass_properties("sphere", radius=radius, density=1.0)
        except ValueError as exc:
            v.fail(where, str(exc))
            continue
        if len(v.problems) > part_before:
            continue
        shapes.append(int(Shape[shape_name.upper()]))
        positions.append(position)
        rotations.append(R)
        radii.append(radius)
        halves.append(half)
        hulls.append(hull)
        volumes.append(volume)
        inertias.append(inertia)
    if len(v.problems) > before or not shapes:
        return
    volumes = np.array(volumes)
    rho = density if density is not None else mass / volumes.sum()
    part_mass = rho * volumes
    total, com, inertia = compound_mass_properties(part_mass, np.array(positions), np.array(rotations),
                                                   rho * np.array(inertias))
    offsets = np.array(positions) - com
    spec.mass, spec.inertia_body = total, inertia
    spec.parts = CompoundParts(shape=np.array(shapes, np.int8), position=offsets, rotation=np.array(rotations),
                               radius=np.array(radii), half_extents=np.array(halves), hulls=hulls, mass=part_mass)
    spec.half_extents = compound_half_extents(spec.parts)
    spec.position = com


def compound_half_extents(parts: CompoundParts) -> np.ndarray:
    """(3,) half extents of a box about the body's COM holding every part (the parts turned into body axes)."""
    reach = np.zeros(3)
    for k in range(parts.count):
        R, p = parts.rotation[k], parts.position[k]
        if parts.hulls[k] is not None:
            corners = parts.hulls[k].vertices @ R.T + p
            reach = np.maximum(reach, np.abs(corners).max(axis=0))
        else:
            half = np.abs(R) @ parts.half_extents[k] + parts.radius[k]
            reach = np.maximum(reach, np.abs(p) + half)
    return reach

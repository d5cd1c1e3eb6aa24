"""Reading triangle meshes from STL (ASCII and binary) and OBJ files, bounded, into plain arrays.

Parsing is trimesh's (``trimesh.load`` on the bytes, ``process=False``); what this module adds is the bounds and
the errors a scene needs: the file read by :func:`cgp_core.user_input.read_user_file` (only a regular file after
resolving symbolic links, its size checked before a byte is read: :data:`MAX_FILE_BYTES`), at most
:data:`MAX_VERTICES` vertices and :data:`MAX_TRIANGLES` triangles (the caps are :mod:`cgp_core.limits`'), and every
error a :class:`MeshFileError` naming the file and the reason — cannot read, not a mesh, empty, too big, not
closed (asked for where closure matters: the mass properties of a movable body need a closed surface, a static
terrain need not be closed).

The result is plain arrays: ``vertices (V, 3)`` float64 and ``triangles (T, 3)`` int64, vertices merged where
their coordinates are equal (an STL file stores each triangle's corners separately), triangles that repeat a
vertex (zero area by construction) dropped.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from ..inertia import closed_surface_problem
from ..limits import MAX_MESH_FILE_BYTES, MAX_MESH_TRIANGLES, MAX_MESH_VERTICES
from ..user_input import UserInputError, read_user_file

#: file size read at most, vertices and triangles accepted after merging (:mod:`cgp_core.limits`)
MAX_FILE_BYTES = MAX_MESH_FILE_BYTES
MAX_VERTICES = MAX_MESH_VERTICES
MAX_TRIANGLES = MAX_MESH_TRIANGLES
#: the file types read (by suffix, case-insensitive)
FILE_TYPES = {".stl": "stl", ".obj": "obj"}


class MeshFileError(ValueError):
    """A mesh file that cannot be used; the message names the file and the reason."""


def load_mesh(path, *, closed: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Read a mesh file: ``(vertices (V, 3) float64, triangles (T, 3) int64)``.

    Args:
        path: an ``.stl`` or ``.obj`` file (symbolic links are followed; the target must be a regular file).
        closed: require a closed, consistently oriented surface (every edge shared by exactly two triangles,
            in opposite directions) — for a movable body's mass properties.

    Raises:
        MeshFileError: naming the file and why (see the module docstring).
    """
    given = Path(path)
    name = str(given)
    try:
        resolved = given.expanduser().resolve()
    except (OSError, RuntimeError):  # a link loop: the reader says so
        resolved = given
    file_type = FILE_TYPES.get(resolved.suffix.lower()) or FILE_TYPES.get(given.suffix.lower())
    if file_type is None:
        raise MeshFileError(f"mesh file {name}: unknown file type {resolved.suffix!r} (read: "
                            f"{', '.join(FILE_TYPES)})")
    try:
        data = read_user_file(given, max_bytes=MAX_FILE_BYTES)
    except UserInputError as error:
        reason = str(error)
        if "bytes; files are limited" in reason:
            reason = f"too big: {reason}"
        elif not reason.startswith("cannot"):
            reason = f"cannot read: {reason}"
        raise MeshFileError(f"mesh file {name}: {reason}") from None
    if not data:
        raise MeshFileError(f"mesh file {name}: empty (0 bytes)")
    vertices, faces = _parse(data, file_type, name)
    if len(vertices) == 0 or len(faces) == 0:
        raise MeshFileError(f"mesh file {name}: empty: no triangles")
    if len(faces) > MAX_TRIANGLES:
        raise MeshFileError(f"mesh file {name}: too big: {len(faces)} triangles, more than the {MAX_TRIANGLES} "
                            "allowed (simplify the mesh)")
    if not np.isfinite(vertices).all():
        raise MeshFileError(f"mesh file {name}: not a mesh: a vertex coordinate is not a finite number")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshFileError(f"mesh file {name}: not a mesh: a face indexes a vertex that does not exist")
    # merge equal vertices, drop triangles that repeat one
    unique, inverse = np.unique(vertices, axis=0, return_inverse=True)
    triangles = inverse.reshape(-1)[faces].astype(np.int64)
    keep = (triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2]) \
        & (triangles[:, 0] != triangles[:, 2])
    triangles = triangles[keep]
    if len(triangles) == 0:
        raise MeshFileError(f"mesh file {name}: empty: every triangle has zero area")
    used = np.unique(triangles)
    if len(used) > MAX_VERTICES:
        raise MeshFileError(f"mesh file {name}: too big: {len(used)} vertices, more than the {MAX_VERTICES} "
                            "allowed (simplify the mesh)")
    local = np.full(len(unique), -1, np.int64)
    local[used] = np.arange(len(used))
    vertices = np.ascontiguousarray(unique[used], dtype=np.float64)
    triangles = np.ascontiguousarray(local[triangles])
    if closed:
        problem = closed_surface_problem(triangles)
        if problem:
            raise MeshFileError(f"mesh file {name}: not closed, so it bounds no solid (a movable body needs a "
                                f"closed mesh): {problem}")
    return vertices, triangles


def _parse(data: bytes, file_type: str, name: str) -> tuple[np.ndarray, np.ndarray]:
    """trimesh's parser on the bytes: ``(vertices (n, 3), faces (t, 3))`` as read (triangulated)."""
    import trimesh

    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=file_type, force="mesh", process=False)
    except MeshFileError:
        raise
    except Exception as error:  # trimesh raises many kinds (ValueError, IndexError, struct.error ...)
        raise MeshFileError(f"mesh file {name}: not a mesh: the {file_type.upper()} parser failed "
                            f"({type(error).__name__}: {str(error)[:200]})") from None
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=float).reshape(-1, 3)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3)
    return vertices, faces

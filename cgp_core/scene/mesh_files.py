"""The mesh files a scene names (``mesh:`` of a convex body or part, of a static mesh): where a ``mesh:`` value
points, ``scale``, reading a file once (:func:`cgp_core.collision.meshfile.load_mesh`) and holding its numbers
to the ranges every scene key is held to (:mod:`cgp_core.limits`), after the scale, before anything is built
from them.

A file is parsed at most once per request, and at most once while it is unchanged: what was read — or why it was
refused — is kept per request (:attr:`.validation.Validator.files`) and in a small cache across requests (a pile
of rocks spawned one by one from one STL file, a compound body of many parts naming one file: issue 38 measured
256 parts each parsing one 32 MB OBJ, ~37 minutes).  The files one request reads are at most
:data:`cgp_core.limits.MAX_MESH_BYTES_PER_REQUEST` bytes together, each file counted once, checked (by its size)
before it is read."""

from __future__ import annotations

import threading
from collections import OrderedDict
from importlib import resources
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ..limits import MAX_COORDINATE, MAX_LENGTH, MAX_MESH_BYTES_PER_REQUEST, MIN_LENGTH
from .validation import Validator, short_repr


class MeshRead(NamedTuple):
    """A mesh file as a scene key uses it."""

    path: Path             # as the key named it (resolved against the scene file's directory)
    identity: tuple        # (resolved path, size, mtime in ns): the file's contents, for the caches
    vertices: np.ndarray   # (V, 3) float64 [m], scaled
    file_vertices: np.ndarray  # (V, 3) float64, as the file gives them (shared with the caches: not to be edited)
    triangles: np.ndarray  # (T, 3) int64
    scale: tuple           # (sx, sy, sz) applied


def builtin_mesh_dir() -> Path:
    """The meshes shipped with the package (``msgs_config/meshes``): where a relative ``mesh:`` not found next to
    the scene file is looked for."""
    return Path(str(resources.files("msgs_config") / "meshes"))


def parse_scale(v: Validator, raw: dict, key: str) -> np.ndarray | None:
    """``scale``: a positive factor or three ([sx, sy, sz]); (3,)."""
    if "scale" not in raw:
        return np.ones(3)
    value = raw["scale"]
    if isinstance(value, (list, tuple)):
        before = len(v.problems)
        scale = v.vector(value, f"{key}.scale", 3, minimum=0.0, exclusive_min=True)
        return scale if len(v.problems) == before else None
    before = len(v.problems)
    factor = v.number(value, f"{key}.scale", minimum=0.0, exclusive_min=True, default=1.0)
    return np.full(3, factor) if len(v.problems) == before else None


def mesh_path(v: Validator, value: Any, key: str) -> Path | None:
    """Where a ``mesh:`` value points: a ``file://`` URI or an absolute path as given; a relative path from the
    scene file's directory (a spawn request's ``uri``: that file's), else from the built-in meshes
    (:func:`builtin_mesh_dir`)."""
    from urllib.parse import unquote, urlparse

    text = v.string(value, key)
    if not text.strip():
        v.fail(key, "must name a mesh file (.stl or .obj): a path, or a file:// URI")
        return None
    parsed = urlparse(text)
    if parsed.scheme == "file":
        return Path(unquote(parsed.path))
    if parsed.scheme and len(parsed.scheme) > 1:
        v.fail(key, f"{short_repr(text)}: only local files are read (a path, or a file:// URI), not {parsed.scheme}:")
        return None
    path = Path(text).expanduser()
    if path.is_absolute():
        return path
    source = Path(v.source)
    candidates = ([source.parent / path] if source.is_file() else []) + [builtin_mesh_dir() / path]
    return next((c for c in candidates if c.exists()), candidates[0])


def scaled_points_problem(points: np.ndarray, *, solid: bool) -> str | None:
    """Why ``points (n, 3)`` (a mesh's vertices or a hull's points, scaled) are not what cgp_sim simulates, or
    None: every coordinate within ±MAX_COORDINATE m, the largest extent at least MIN_LENGTH m and, for a
    ``solid`` body's shape (a convex body or part, not a static mesh), at most MAX_LENGTH m — the ranges of the
    scene's own coordinates and lengths (:mod:`cgp_core.limits`)."""
    with np.errstate(over="ignore", invalid="ignore"):
        reach = float(np.abs(points).max(initial=0.0))
        extent = float((points.max(axis=0) - points.min(axis=0)).max()) if len(points) else 0.0
    if not np.isfinite(reach) or reach > MAX_COORDINATE:
        return (f"its coordinates reach {reach:g} m after the scale; they must be within ±{MAX_COORDINATE:g} m "
                "(what cgp_sim simulates: cgp_core.limits)")
    if extent < MIN_LENGTH:
        return (f"it is {extent:g} m across after the scale; a shape is at least {MIN_LENGTH:g} m across (what "
                "cgp_sim simulates: cgp_core.limits)")
    if solid and extent > MAX_LENGTH:
        return (f"it is {extent:g} m across after the scale; a body is at most {MAX_LENGTH:g} m across (what "
                "cgp_sim simulates: cgp_core.limits)")
    return None


def read_mesh(v: Validator, raw: dict, key: str, *, solid: bool) -> MeshRead | None:
    """The ``mesh`` key of ``raw`` read, scaled by its ``scale`` and held to :func:`scaled_points_problem` (a
    ``solid`` body's shape, or a static mesh); None with the problem recorded at ``key.mesh`` / ``key.scale``."""
    from ..collision.meshfile import MeshFileError, load_mesh

    scale = parse_scale(v, raw, key)
    path = mesh_path(v, raw.get("mesh"), f"{key}.mesh")
    if path is None or scale is None:
        return None
    identity = file_identity(path)
    try:
        known = v.files.get(identity)
        if identity is None:  # cannot be looked at: the reader names why
            known = load_mesh(path)
        elif known is None:
            spent = sum(ident[1] for ident in v.files)
            if spent + identity[1] > MAX_MESH_BYTES_PER_REQUEST:
                v.fail(f"{key}.mesh", f"{path.name}: {identity[1]} bytes after {spent} bytes of other mesh files; "
                       f"the mesh files of one scene or request are at most {MAX_MESH_BYTES_PER_REQUEST} bytes "
                       "together (cgp_core.limits)")
                return None
            known = v.files[identity] = cached(("mesh", identity), lambda: load_mesh(path))
        vertices, triangles = known
    except MeshFileError as exc:
        v.fail(f"{key}.mesh", str(exc))
        return None
    with np.errstate(over="ignore", invalid="ignore"):  # a product past float64 is inf, refused just below
        scaled = vertices * scale
    problem = scaled_points_problem(scaled, solid=solid)
    if problem:
        v.fail(f"{key}.scale" if "scale" in raw else f"{key}.mesh", f"{path.name}: {problem}")
        return None
    return MeshRead(path, identity, scaled, vertices, triangles, tuple(float(s) for s in scale))


def file_identity(path: Path) -> tuple | None:
    """``(resolved path, size, mtime in ns)`` of a file, or None if it cannot be looked at (the reader says why)."""
    try:
        stat = path.stat()
        return (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    except (OSError, RuntimeError):
        return None


# ---- the cache across requests ----------------------------------------------------------------------------

#: what was read or built from mesh files (parsed meshes, hulls, BVHs — or the error that refused them), by a key
#: naming the file's identity and what was made of it; the oldest entries go beyond these bounds
MESH_CACHE_ENTRIES = 32
MESH_CACHE_BYTES = 256 * 1024 * 1024
_CACHE: OrderedDict = OrderedDict()  # key -> (value or exception, bytes)
_CACHE_LOCK = threading.Lock()


def cached(key: tuple, build):
    """``build()``, or what it gave the last time for ``key`` — or the refusal it raised (a ValueError: a
    MeshFileError, a HullError), raised again."""
    with _CACHE_LOCK:
        hit = _CACHE.get(key)
        if hit is not None:
            _CACHE.move_to_end(key)
    if hit is None:
        try:
            value = build()
        except ValueError as exc:
            value = exc
        hit = (value, 0 if isinstance(value, ValueError) else _nbytes(value))
        with _CACHE_LOCK:
            _CACHE[key] = hit
            while len(_CACHE) > 1 and (len(_CACHE) > MESH_CACHE_ENTRIES
                                       or sum(b for _, b in _CACHE.values()) > MESH_CACHE_BYTES):
                _CACHE.popitem(last=False)
    value = hit[0]
    if isinstance(value, ValueError):
        raise type(value)(*value.args)  # a new one: raising the kept one would grow its traceback each time
    return value


def _nbytes(value) -> int:
    """Bytes of the arrays in ``value`` (an array, a tuple of them, or an object with ``nbytes`` or arrays as
    attributes)."""
    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, tuple):
        return sum(_nbytes(x) for x in value)
    if hasattr(value, "nbytes"):
        return int(value.nbytes)
    return sum(x.nbytes for x in vars(value).values() if isinstance(x, np.ndarray))

"""Reading triangle meshes from STL (ASCII and binary) and OBJ files, bounded, into plain arrays.

The parsers are this module's own, each linear in the file's bytes (issue 38: trimesh's, used before, took
quadratic time on an ASCII STL of many ``solid`` blocks or an OBJ of many groups, and reported a malformed binary
STL as a missing optional dependency of its own).  They read the geometry only: an STL's facets (its normals and
attribute bytes are ignored: the winding gives the front), an OBJ's ``v`` and ``f`` lines (``f`` indices as
``i``, ``i/j``, ``i//k`` or ``i/j/k``, negative ones relative to the vertices read so far; a polygon of k
corners becomes k − 2 triangles, a fan from its first corner; every other line — ``vt``, ``vn``, ``g``, ``o``,
``usemtl``, ``mtllib``, ``s``, ``l``, comments — is skipped).

Bounds, each checked before the cost it bounds is paid: the file is read by
:func:`cgp_core.user_input.read_user_file` (only a regular file after resolving symbolic links, its size checked
before a byte is read: :data:`MAX_FILE_BYTES`); the triangle count a scan can give (a binary STL's header, an
ASCII STL's ``endfacet`` count, an OBJ's ``f`` lines) is held to :data:`MAX_TRIANGLES` before anything is parsed,
and again after an OBJ's polygons are split; a number's text is at most :data:`MAX_NUMBER_CHARACTERS`
characters; at most :data:`MAX_VERTICES` vertices after merging (the caps are :mod:`cgp_core.limits`').  Every
error is a :class:`MeshFileError` naming the file and the reason (cannot read, not a mesh — with the line or the
record —, empty, too big, not closed where closure is asked for: the mass properties of a movable body need a
closed surface, a static terrain need not be closed).  The numbers are not held to the scene's ranges here: a
scene's ``scale`` comes first (:mod:`cgp_core.scene.shapes` checks the scaled coordinates).

The result is plain arrays: ``vertices (V, 3)`` float64 and ``triangles (T, 3)`` int64, vertices merged where
their coordinates are equal (an STL file stores each triangle's corners separately), triangles that repeat a
vertex (zero area by construction) dropped.  :func:`parse_mesh` is the same on bytes already read: a plain
function of picklable inputs, for a worker process.
"""

from __future__ import annotations

import re
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
#: characters of one number's text (a float64 needs at most 24; longer is not a number of a mesh, and the
#: parsers' token arrays are as wide as their widest token)
MAX_NUMBER_CHARACTERS = 64

#: a binary STL: an 80-byte header, a little-endian uint32 triangle count, then 50 bytes per triangle
_STL_HEADER_BYTES = 84
_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
_NUMBER = rb"(\S{1,%d})" % MAX_NUMBER_CHARACTERS
#: one ASCII STL facet (the text lower-cased first): its nine corner coordinates
_ASCII_FACET = re.compile(rb"facet\s+normal\s+\S+\s+\S+\s+\S+\s+outer\s+loop"
                          + rb"\s+vertex\s+" + rb"\s+".join([_NUMBER] * 3)
                          + rb"\s+vertex\s+" + rb"\s+".join([_NUMBER] * 3)
                          + rb"\s+vertex\s+" + rb"\s+".join([_NUMBER] * 3)
                          + rb"\s+endloop\s+endfacet")
_ASCII_END = re.compile(rb"endfacet")
#: numbers converted at a time (bounds the memory of the conversion: 64 MB at the widest numbers)
_CHUNK_TOKENS = 1 << 20
#: the OBJ lines this reader uses: ``v`` and ``f``, and the rest of the line
_OBJ_V = re.compile(rb"^[ \t]*v[ \t]+([^\r\n#]*)", re.MULTILINE)
_OBJ_F = re.compile(rb"^[ \t]*f[ \t]+([^\r\n#]*)", re.MULTILINE)
#: what follows a corner's vertex index (``/j``, ``//k``, ``/j/k``)
_OBJ_CORNER_REST = re.compile(rb"/[^ \t]*")


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
    return parse_mesh(data, file_type, name, closed=closed)


def parse_mesh(data: bytes, file_type: str, name: str, *, closed: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """:func:`load_mesh` on the bytes of a file already read: ``file_type`` ``"stl"`` or ``"obj"``, ``name`` for
    the messages.  Raises :class:`MeshFileError`."""
    if not data:
        raise MeshFileError(f"mesh file {name}: empty (0 bytes)")
    if len(data) > MAX_FILE_BYTES:
        raise MeshFileError(f"mesh file {name}: too big: {len(data)} bytes; files are limited to {MAX_FILE_BYTES}")
    vertices, faces = (_parse_stl if file_type == "stl" else _parse_obj)(data, name)
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
    unique, inverse = _merge_equal(vertices)
    triangles = inverse[faces]
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


def _merge_equal(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(points, axis=0, return_inverse=True)`` for finite ``points (n, 3)``, 18x faster (one lexsort
    of the columns instead of a sort of structured rows: 0.1 s for 1.5 million): ``(unique rows (u, 3) in
    lexicographic order, inverse (n,) int64)``; −0.0 is 0.0."""
    points = points + 0.0  # -0.0 + 0.0 is 0.0: equal rows are then equal bytes, as the comparison below wants
    order = np.lexsort((points[:, 2], points[:, 1], points[:, 0]))
    ordered = points[order]
    first = np.ones(len(ordered), bool)
    np.any(ordered[1:] != ordered[:-1], axis=1, out=first[1:])
    inverse = np.empty(len(points), np.int64)
    inverse[order] = np.cumsum(first) - 1
    return ordered[first], inverse


def _too_many_triangles(name: str, count: int, where: str) -> MeshFileError:
    return MeshFileError(f"mesh file {name}: too big: {where} {count} triangles, more than the {MAX_TRIANGLES} "
                         "allowed (simplify the mesh)")


# ---- STL ------------------------------------------------------------------------------------------------

def _parse_stl(data: bytes, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(corners (3t, 3), faces (t, 3))``: a binary STL if its size is what its header's count says, else an
    ASCII one if it starts with ``solid``, else a binary one whose size is wrong (refused, saying so)."""
    count = int.from_bytes(data[80:84], "little") if len(data) >= _STL_HEADER_BYTES else -1
    if count >= 0 and len(data) == _STL_HEADER_BYTES + _STL_RECORD.itemsize * count:
        return _parse_binary_stl(data, count, name)
    if data.lstrip()[:5].lower() == b"solid":
        return _parse_ascii_stl(data, name)
    if count < 0:
        raise MeshFileError(f"mesh file {name}: not a mesh: {len(data)} bytes, neither an ASCII STL (it does not "
                            f"start with 'solid') nor a binary one (its header alone is {_STL_HEADER_BYTES} bytes)")
    records, rest = divmod(len(data) - _STL_HEADER_BYTES, _STL_RECORD.itemsize)
    raise MeshFileError(f"mesh file {name}: not a mesh: a binary STL whose header gives {count} triangles "
                        f"({_STL_HEADER_BYTES + _STL_RECORD.itemsize * count} bytes), but the file has {len(data)} "
                        f"bytes: {records} whole 50-byte triangle records" + (f" and {rest} bytes of a cut one"
                                                                              if rest else ""))


def _parse_binary_stl(data: bytes, count: int, name: str) -> tuple[np.ndarray, np.ndarray]:
    if count > MAX_TRIANGLES:
        raise _too_many_triangles(name, count, "its binary STL header gives")
    records = np.frombuffer(data, dtype=_STL_RECORD, count=count, offset=_STL_HEADER_BYTES)
    corners = records["corners"].reshape(-1, 3).astype(np.float64)
    return corners, np.arange(3 * count, dtype=np.int64).reshape(-1, 3)


def _parse_ascii_stl(data: bytes, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Every ``facet`` of every ``solid`` (one pass of one regular expression: linear in the bytes)."""
    text = data.lower()
    count = text.count(b"endfacet")
    if count > MAX_TRIANGLES:
        raise _too_many_triangles(name, count, "its ASCII STL has")
    ends, chunks, chunk, converted = set(), [], [], 0
    try:
        for match in _ASCII_FACET.finditer(text):
            ends.add(match.end())
            chunk += match.groups()
            if len(chunk) >= _CHUNK_TOKENS:
                chunks.append(_convert(chunk, np.float64))
                converted, chunk = converted + len(chunk), []
        if len(ends) == count:
            chunks.append(_convert(chunk, np.float64))
    except _BadToken as bad:
        facet = next(m for k, m in enumerate(_ASCII_FACET.finditer(text)) if k == (converted + bad.index) // 9)
        line = text.count(b"\n", 0, facet.start()) + 1
        raise MeshFileError(f"mesh file {name}: not a mesh: line {line}: a vertex coordinate of the facet there is "
                            "not a number") from None
    if len(ends) != count:
        end = next((e.end() for e in _ASCII_END.finditer(text) if e.end() not in ends), len(text))
        line = text.count(b"\n", 0, end) + 1
        raise MeshFileError(f"mesh file {name}: not a mesh: the ASCII STL facet ending on line {line} is not "
                            "'facet normal nx ny nz / outer loop / vertex x y z (three times) / endloop / endfacet' "
                            f"(numbers of at most {MAX_NUMBER_CHARACTERS} characters)")
    corners = np.concatenate(chunks).reshape(-1, 3)
    return corners, np.arange(len(corners), dtype=np.int64).reshape(-1, 3)


class _BadToken(Exception):
    """The ``index``-th token of those converted is not a number (an index: not an int64)."""

    def __init__(self, index: int):
        super().__init__(index)
        self.index = index


def _convert(tokens: list[bytes], dtype) -> np.ndarray:
    """``tokens`` (each at most :data:`MAX_NUMBER_CHARACTERS` bytes, at most :data:`_CHUNK_TOKENS` of them: the
    array converted is as wide as the widest) as ``dtype`` (float64 or int64) (n,); raises :class:`_BadToken`
    for the first that is not one.  (Refusals never quote a file: a mesh "file" may be a link to any file.)"""
    try:
        return np.array(tokens, dtype=np.bytes_).astype(dtype).reshape(-1)
    except (ValueError, OverflowError):
        parse = float if dtype == np.float64 else int
        for k, token in enumerate(tokens):
            try:
                value = parse(token)
            except ValueError:
                raise _BadToken(k) from None
            if parse is int and not -(2**63) <= value < 2**63:
                raise _BadToken(k) from None
        raise


# ---- OBJ ------------------------------------------------------------------------------------------------

def _parse_obj(data: bytes, name: str) -> tuple[np.ndarray, np.ndarray]:
    """The ``v`` and ``f`` lines (each kind found by one scan; every other line is skipped without being split)."""
    face_rests = _OBJ_F.findall(data)
    if len(face_rests) > MAX_TRIANGLES:
        raise _too_many_triangles(name, len(face_rests), "its OBJ has at least (one per f line)")
    vertex_fields = [rest.split() for rest in _OBJ_V.findall(data)]
    short = next((k for k, f in enumerate(vertex_fields) if len(f) < 3), None)
    if short is not None:
        raise _obj_error(data, _OBJ_V, short, name, "a 'v' line needs x y z")
    coordinates = [x for fields in vertex_fields for x in fields[:3]]
    long = next((k for k, x in enumerate(coordinates) if len(x) > MAX_NUMBER_CHARACTERS), None)
    if long is not None:
        raise _obj_error(data, _OBJ_V, long // 3, name, f"a 'v' coordinate of more than {MAX_NUMBER_CHARACTERS} "
                         "characters")
    chunks = [np.zeros(0)]
    for first in range(0, len(coordinates), _CHUNK_TOKENS):
        try:
            chunks.append(_convert(coordinates[first:first + _CHUNK_TOKENS], np.float64))
        except _BadToken as bad:
            raise _obj_error(data, _OBJ_V, (first + bad.index) // 3, name, "a 'v' coordinate is not a number") \
                from None
    points = np.concatenate(chunks).reshape(-1, 3)
    vertices = len(points)
    sizes = np.array([len(rest.split()) for rest in face_rests], dtype=np.int64)
    if (sizes < 3).any():
        raise _obj_error(data, _OBJ_F, int(np.flatnonzero(sizes < 3)[0]), name, "an 'f' line needs at least 3 "
                         "corners")
    triangle_count = int(sizes.sum()) - 2 * len(sizes)
    if triangle_count > MAX_TRIANGLES:
        raise _too_many_triangles(name, triangle_count, "its OBJ's polygons make")
    if not len(sizes):
        return points, np.zeros((0, 3), np.int64)
    corners = _OBJ_CORNER_REST.sub(b"", b" ".join(face_rests)).split()
    if len(corners) != int(sizes.sum()):  # a corner that is only "/...": no index
        raise MeshFileError(f"mesh file {name}: not a mesh: an 'f' corner without a vertex index (i, i/j, i//k or "
                            "i/j/k)")
    chunks = []
    for first in range(0, len(corners), _CHUNK_TOKENS):
        try:
            chunks.append(_convert(corners[first:first + _CHUNK_TOKENS], np.int64))
        except _BadToken as bad:
            face = int(np.searchsorted(np.cumsum(sizes), first + bad.index, side="right"))
            raise _obj_error(data, _OBJ_F, face, name, "an 'f' corner is not a vertex index (i, i/j, i//k or i/j/k "
                             "with i an integer within int64)") from None
    index = np.concatenate(chunks)
    # a positive index may name a vertex defined later (as common readers allow); a negative one counts back
    # from the last vertex defined before its line (compared as index >= -base: -index overflows at -2**63)
    base = np.zeros(len(index), np.int64)
    if (index < 0).any():
        vertex_at = np.array([m.start() for m in _OBJ_V.finditer(data)], dtype=np.int64)
        face_at = np.array([m.start() for m in _OBJ_F.finditer(data)], dtype=np.int64)
        base = np.repeat(np.searchsorted(vertex_at, face_at), sizes)
    valid = ((index > 0) & (index <= vertices)) | ((index < 0) & (index >= -base))
    if not valid.all():
        k = int(np.flatnonzero(~valid)[0])
        face = int(np.searchsorted(np.cumsum(sizes), k, side="right"))
        raise _obj_error(data, _OBJ_F, face, name, f"an 'f' corner names vertex {index[k]}, but the file defines "
                         f"{vertices} vertices" + (f", {base[k]} of them before that line" if index[k] < 0 else "")
                         + " (OBJ counts from 1; a negative index counts back from the last one before the line)")
    return points, _fans(np.where(index > 0, index - 1, base + index), sizes)


def _fans(corners: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """The triangles ``(Σ (k − 2), 3)`` of polygons given as their ``corners`` one after another (``sizes`` (f,)
    corners each): fans from each polygon's first corner."""
    first = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    per_face = sizes - 2
    face = np.repeat(np.arange(len(sizes)), per_face)
    step = np.arange(len(face)) - np.repeat(np.cumsum(per_face) - per_face, per_face)
    start = first[face]
    return np.stack([corners[start], corners[start + step + 1], corners[start + step + 2]], axis=1)


def _obj_error(data: bytes, kind: re.Pattern, ordinal: int, name: str, reason: str) -> MeshFileError:
    """A malformed line: the ``ordinal``-th (from 0) that ``kind`` matches, its line number found only now that
    the file is refused."""
    for k, match in enumerate(kind.finditer(data)):
        if k == ordinal:
            line = data.count(b"\n", 0, match.start()) + 1
            return MeshFileError(f"mesh file {name}: not a mesh: line {line}: {reason}")
    return MeshFileError(f"mesh file {name}: not a mesh: {reason}")

"""Issue 38, mesh files: our STL / OBJ parsers read what an independent reader (trimesh) reads, stay linear in the
file (many ``solid`` blocks, many groups), refuse a malformed file with its real reason, read a file once per
request (refusals too), and hold a file's numbers to the scene's ranges after ``scale`` (rows D5, D6, D7, D8, D9).

The two "within a bound" tests guard against a parser or a pass that is quadratic again: their bounds are tens of
times what the code takes (the old code took hours, or minutes); the figures themselves are benchmarks/bench_mesh.py.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cgp_core.collision import meshfile
from cgp_core.collision.meshfile import MeshFileError, load_mesh, parse_mesh
from cgp_core.scene import SceneError, parse_scene


def binary_stl(corners: np.ndarray, count: int | None = None) -> bytes:
    """A binary STL of ``corners (t, 3, 3)``; ``count``: what the header claims (default: t)."""
    record = np.zeros(len(corners), dtype=[("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    record["corners"] = corners
    return b"\0" * 80 + struct.pack("<I", len(corners) if count is None else count) + record.tobytes()


def ascii_stl(corners: np.ndarray, per_solid: int = 1) -> bytes:
    """An ASCII STL of ``corners (t, 3, 3)``, a ``solid`` block per ``per_solid`` facets."""
    lines = []
    for i, facet in enumerate(corners):
        if i % per_solid == 0:
            lines.append(f"solid part{i}")
        lines += ["  facet normal 0 0 0", "    outer loop"]
        lines += ["      vertex " + " ".join(repr(float(x)) for x in corner) for corner in facet]
        lines += ["    endloop", "  endfacet"]
        if i % per_solid == per_solid - 1 or i == len(corners) - 1:
            lines.append(f"endsolid part{i}")
    return ("\n".join(lines) + "\n").encode()


def obj(vertices: np.ndarray, faces: list, *, groups: bool = False, negative: bool = False) -> bytes:
    """An OBJ of ``vertices (v, 3)`` and ``faces`` (lists of 0-based corners, any length ≥ 3): each face after
    all vertices, in a group and material of its own (``groups``), indexed back from the last vertex
    (``negative``)."""
    lines = ["v " + " ".join(repr(float(x)) for x in vertex) for vertex in vertices]
    for i, face in enumerate(faces):
        if groups:
            lines += [f"g g{i}", f"usemtl m{i}"]
        corners = [str(c - len(vertices)) if negative else f"{c + 1}/{c + 1}" for c in face]
        lines.append("f " + " ".join(corners))
    return ("\n".join(lines) + "\n").encode()


def soup(vertices: np.ndarray, triangles: np.ndarray) -> list:
    """The triangles as coordinate tuples, each turned to start at its least corner (its winding kept), sorted:
    what a mesh is, whatever its numbering."""
    out = []
    for t in triangles:
        corners = [tuple(float(x) for x in vertices[i]) for i in t]
        first = corners.index(min(corners))
        out.append(tuple(corners[first:] + corners[:first]))
    return sorted(out)


# ---- the parsers against an independent reader ----------------------------------------------------------

COORDINATE = st.floats(-1e3, 1e3, allow_nan=False, width=32)  # (exact in a binary STL's float32 too)


@settings(max_examples=30, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(COORDINATE, COORDINATE, COORDINATE), min_size=3, max_size=12, unique=True),
       st.data())
def test_parsers_read_what_trimesh_reads(points, data):
    trimesh = pytest.importorskip("trimesh")
    vertices = np.array(points, dtype=float)
    n = len(vertices)
    faces = data.draw(st.lists(st.lists(st.integers(0, n - 1), min_size=3, max_size=5, unique=True), min_size=1,
                               max_size=10))
    triangles = np.array([[f[0], f[k], f[k + 1]] for f in faces for k in range(1, len(f) - 1)])
    files = {"stl": [binary_stl(vertices[triangles]), ascii_stl(vertices[triangles], per_solid=2)],
             "obj": [obj(vertices, faces, groups=True), obj(vertices, faces, negative=True)]}
    for file_type, texts in files.items():
        for text in texts:
            import io

            theirs = trimesh.load(io.BytesIO(text), file_type=file_type, force="mesh", process=False)
            their_soup = [t for t in soup(np.asarray(theirs.vertices), np.asarray(theirs.faces))
                          if len(set(t)) == 3]  # (we drop a triangle that repeats a point)
            try:
                ours = parse_mesh(text, file_type, "fuzz")
            except MeshFileError as exc:
                assert not their_soup and "every triangle has zero area" in str(exc)
                continue
            assert soup(*ours) == their_soup


def test_obj_polygons_negative_indices_and_other_lines():
    text = (b"# a comment\nmtllib m.mtl\no thing\nv 0 0 0\nv 1 0 0 # x\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n"
            b"g side\nusemtl red\ns 1\nf 1/1/1 2//1 3/1 4\nl 1 2\nf -4 -3 -2\n")
    vertices, triangles = parse_mesh(text, "obj", "quad.obj")
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    assert soup(vertices, triangles) == soup(square, np.array([[0, 1, 2], [0, 2, 3], [0, 1, 2]]))


# ---- D7: a malformed file is refused with its real reason -------------------------------------------------

def test_a_malformed_binary_stl_is_refused_with_its_reason(tmp_path):
    """Old code: "the STL parser failed (ModuleNotFoundError: No module named 'charset_normalizer')"."""
    good = binary_stl(np.random.default_rng(1).normal(size=(100, 3, 3)))
    (tmp_path / "claims.stl").write_bytes(good[:80] + struct.pack("<I", 10**9) + good[84:])
    with pytest.raises(MeshFileError, match=r"claims.stl: not a mesh: a binary STL whose header gives 1000000000 "
                                            r"triangles \(50000000084 bytes\), but the file has 5084 bytes"):
        load_mesh(tmp_path / "claims.stl")
    (tmp_path / "cut.stl").write_bytes(good[:84 + 50 * 40 + 17])
    with pytest.raises(MeshFileError, match="cut.stl: not a mesh: .* 40 whole 50-byte triangle records and 17 "
                                            "bytes of a cut one"):
        load_mesh(tmp_path / "cut.stl")
    (tmp_path / "tiny.stl").write_bytes(b"\x01\x02")
    with pytest.raises(MeshFileError, match="tiny.stl: not a mesh: 2 bytes, neither an ASCII STL"):
        load_mesh(tmp_path / "tiny.stl")


@pytest.mark.parametrize("text, reason", [
    (b"solid a\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nendloop\nendfacet\nendsolid a\n",
     "the ASCII STL facet ending on line 7 is not"),
    (b"solid a\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 x1\nvertex 0 1 0\nendloop\nendfacet\n",
     "line 2: a vertex coordinate of the facet there is not a number"),
    (b"solid a\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 " + b"1" * 65
     + b"\nvertex 0 1 0\nendloop\nendfacet\n", "numbers of at most 64 characters"),
])
def test_a_malformed_ascii_stl_is_refused_naming_the_facet(text, reason):
    with pytest.raises(MeshFileError, match=reason):
        parse_mesh(text, "stl", "bad.stl")


@pytest.mark.parametrize("text, reason", [
    (b"v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", "line 2: a 'v' line needs x y z"),
    (b"v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2\n", "line 5: an 'f' line needs at least 3 corners"),
    (b"v 0 0 0\nv 1 0 x\nv 0 1 0\nf 1 2 3\n", "line 2: a 'v' coordinate is not a number"),
    (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", "line 4: an 'f' corner is not a vertex index"),
    (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "line 4: an 'f' corner names vertex 0, but the file defines 3 "
                                                "vertices"),
    (b"v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n", "line 3: an 'f' corner names vertex -3, but the file defines 3 "
                                                   "vertices, 2 of them before that line"),
    (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -9223372036854775808\n", "names vertex -9223372036854775808"),
    (b"v 0 0 0\nv 1 0 0\nv 0 1 0\n# x\nf 1 2 99999999999999999999999\n", "line 5: an 'f' corner is not a vertex "
                                                                          "index"),
])
def test_a_malformed_obj_is_refused_naming_the_line_or_index(text, reason):
    with pytest.raises(MeshFileError, match=reason):
        parse_mesh(text, "obj", "bad.obj")


def test_a_refusal_never_quotes_the_file(tmp_path):
    """A mesh "file" may be a link to any readable file: what it holds is never in the message."""
    secret = tmp_path / "secret.txt"
    secret.write_text("v root:x:0:0 hunter2 s3cret\nf 1 2 3\n")
    (tmp_path / "link.obj").symlink_to(secret)
    (tmp_path / "link.stl").symlink_to(secret)
    for link in ("link.obj", "link.stl"):
        with pytest.raises(MeshFileError) as refused:
            load_mesh(tmp_path / link)
        reason = str(refused.value).split(f"{link}: ", 1)[1]  # (the path itself may hold anything)
        assert not any(word in reason for word in ("root", "hunter2", "s3cret")), reason


# ---- D5: linear parsers -------------------------------------------------------------------------------------

def _triangles(count: int) -> np.ndarray:
    side = int(np.ceil(np.sqrt(count / 2))) + 1
    xs = np.arange(side, dtype=float) * 0.01
    x, y = np.meshgrid(xs, xs, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    i = np.arange(side * side).reshape(side, side)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
    t = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])[:count]
    return v, t


@pytest.mark.timeout(60)
def test_many_solids_and_groups_parse_within_a_bound():
    """A hang guard (the bound is ~100x what it takes): old code took 31 s for 8,000 one-triangle solids and 28 s
    for 8,000 OBJ groups, quadratic — 40,000 of each would take ~13 minutes each."""
    vertices, triangles = _triangles(40_000)
    stl_v, stl_t = parse_mesh(ascii_stl(vertices[triangles]), "stl", "solids.stl")
    obj_v, obj_t = parse_mesh(obj(vertices, triangles.tolist(), groups=True), "obj", "groups.obj")
    assert len(stl_t) == len(obj_t) == 40_000
    assert soup(stl_v, stl_t) == soup(obj_v, obj_t)


def test_triangle_caps_are_checked_before_parsing(monkeypatch):
    """A scan's count refuses the file before a number is converted."""
    monkeypatch.setattr(meshfile, "MAX_TRIANGLES", 10)
    monkeypatch.setattr(meshfile, "_convert", lambda *a: pytest.fail("parsed a file a scan refuses"))
    vertices, triangles = _triangles(11)
    for text, file_type in ((ascii_stl(vertices[triangles]), "stl"), (obj(vertices, triangles.tolist()), "obj"),
                            (binary_stl(vertices[triangles]), "stl")):
        with pytest.raises(MeshFileError, match="too big: .* 11 triangles, more than the 10 allowed"):
            parse_mesh(text, file_type, "big")
    with pytest.raises(MeshFileError, match="too big: its OBJ's polygons make 12 triangles"):
        monkeypatch.setattr(meshfile, "_convert", lambda tokens, dtype: np.zeros(len(tokens), dtype))
        parse_mesh(obj(vertices, [[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13]]), "obj", "fan")


# ---- D6: a file is read once per request -------------------------------------------------------------------

def _reads(monkeypatch) -> list:
    """The mesh files read from disk (a spy on the reader)."""
    reads = []
    real = meshfile.read_user_file

    def spy(path, **kwargs):
        reads.append(str(path))
        return real(path, **kwargs)

    monkeypatch.setattr(meshfile, "read_user_file", spy)
    return reads


def test_a_file_is_read_once_per_request_even_when_refused(tmp_path, monkeypatch):
    """Old code: a compound body of 256 parts naming one refused 32 MB OBJ parsed it 256 times (refusals were not
    cached; ~37 minutes)."""
    reads = _reads(monkeypatch)
    vertices, triangles = _triangles(200)
    bad = tmp_path / "bad.obj"
    bad.write_bytes(obj(vertices, triangles.tolist()) + b"f 1 2 100000\n")  # refused at its last line
    parts = ", ".join(f"{{shape: convex, mesh: bad.obj, scale: {1 + k / 10}}}" for k in range(20))
    scene = f"bodies:\n  - {{name: c, shape: compound, parts: [{parts}], mass: 1}}\n"
    with pytest.raises(SceneError) as refused:
        _scene(tmp_path, scene)
    last = f"line {len(bad.read_bytes().splitlines())}: an 'f' corner names vertex 100000"
    assert len(refused.value.problems) == 20 and all(last in p for p in refused.value.problems)
    assert reads == [str(bad)]
    # a good file: once for all its parts at many scales, and not again for the next request while unchanged
    good = tmp_path / "good.obj"
    good.write_bytes(obj(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]),
                         [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    reads.clear()
    for _ in range(2):
        loaded = _scene(tmp_path, scene.replace("bad.obj", "good.obj"))
    assert reads == [str(good)] and loaded.bodies[0].parts.count == 20
    good.write_bytes(good.read_bytes() + b"# changed\n")
    _scene(tmp_path, scene.replace("bad.obj", "good.obj"))
    assert reads == [str(good)] * 2


def test_the_mesh_files_of_one_request_are_bounded_together(tmp_path, monkeypatch):
    from cgp_core.scene import mesh_files

    reads = _reads(monkeypatch)
    vertices, triangles = _triangles(100)
    text = binary_stl(vertices[triangles])
    monkeypatch.setattr(mesh_files, "MAX_MESH_BYTES_PER_REQUEST", 3 * len(text))
    for k in range(4):
        (tmp_path / f"m{k}.stl").write_bytes(text)
    bodies = "\n".join(f"  - {{name: m{k}, shape: mesh, mesh: m{k}.stl, fixed: true}}" for k in range(4))
    with pytest.raises(SceneError, match=r"bodies\[3\] \(m3\).mesh: m3.stl: 5084 bytes after 15252 bytes of other "
                                         "mesh files; the mesh files of one scene or request are at most 15252"):
        _scene(tmp_path, f"bodies:\n{bodies}\n")
    assert len(reads) == 3  # the fourth refused by its size, before it is read


# ---- D8, D9: a mesh file's numbers held to the scene's ranges, after the scale ------------------------------

def _scene(tmp_path, text: str):
    """``parse_scene`` of ``text`` as the file ``s.yaml`` in ``tmp_path`` (relative mesh files are found there)."""
    (tmp_path / "s.yaml").write_text(text)
    return parse_scene(text, str(tmp_path / "s.yaml"))


def _tetrahedron(path, size: float):
    path.write_bytes(obj(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]) * size,
                         [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))


@pytest.mark.parametrize("body, reason", [
    # D8: 1e303 coordinates scaled by 1e6: were accepted, and their markers carried non-finite points
    ("{shape: mesh, mesh: huge.obj, scale: 1e6, fixed: true}",
     r"\.scale: huge.obj: its coordinates reach inf m after the scale; they must be within ±1e\+06 m"),
    ("{shape: mesh, mesh: huge.obj, fixed: true}", r"\.mesh: huge.obj: its coordinates reach 1e\+303 m"),
    # D9: points at 1e6 scaled by 1e6 (a body at 1e12 m), and a 1 nm body
    ("{shape: convex, points: [[0, 0, 0], [1e6, 0, 0], [0, 1e6, 0], [0, 0, 1e6]], scale: 1e6, mass: 1}",
     r"\.scale: its coordinates reach 1e\+12 m after the scale"),
    ("{shape: convex, mesh: unit.obj, scale: 1e-9, mass: 1}",
     r"\.scale: unit.obj: it is 1e-09 m across after the scale; a shape is at least 0.001 m across"),
    ("{shape: convex, mesh: unit.obj, scale: [1e5, 1, 1], mass: 1}",
     r"\.scale: unit.obj: it is 100000 m across after the scale; a body is at most 10000 m across"),
    ("{shape: compound, parts: [{shape: convex, mesh: unit.obj, scale: 1e-9}], mass: 1}",
     r"parts\[0\]\.scale: unit.obj: it is 1e-09 m across"),
    ("{shape: mesh, mesh: unit.obj, scale: 1e-9, fixed: true}", r"\.scale: unit.obj: it is 1e-09 m across"),
])
def test_mesh_numbers_are_held_to_the_scene_ranges_after_the_scale(tmp_path, body, reason):
    _tetrahedron(tmp_path / "huge.obj", 1e303)
    _tetrahedron(tmp_path / "unit.obj", 1.0)
    with pytest.raises(SceneError, match=reason):
        _scene(tmp_path, f"bodies:\n  - {{name: b, {body[1:]}\n")


def test_a_mesh_within_the_ranges_after_its_scale_is_accepted(tmp_path):
    _tetrahedron(tmp_path / "big.obj", 1e7)  # 10,000 km as written, 1 m as scaled
    scene = _scene(tmp_path, "bodies:\n  - {name: b, shape: convex, mesh: big.obj, scale: 1e-7, mass: 1}\n")
    np.testing.assert_allclose(np.ptp(scene.bodies[0].hull.vertices, axis=0), [1, 1, 1], rtol=1e-12)


def _load_and_build(path: str):
    from cgp_core.collision.bvh import StaticMesh

    vertices, triangles = load_mesh(path)
    return StaticMesh.build(vertices, triangles)


def test_the_expensive_steps_run_in_a_worker_process(tmp_path):
    """Parsing, the BVH and the active edges are plain functions of picklable inputs, with picklable results:
    another process can pay for them (what the node does off its tick's thread)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from cgp_core.collision.bvh import StaticMesh
    from cgp_core.collision.convex import convex_hull

    vertices, triangles = _triangles(500)
    (tmp_path / "m.stl").write_bytes(binary_stl(vertices[triangles]))
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        theirs = pool.submit(_load_and_build, str(tmp_path / "m.stl")).result(timeout=120)
        hull = pool.submit(convex_hull, vertices + [0, 0, 1] * (vertices[:, :1] > 0.05)).result(timeout=120)
    ours = _load_and_build(str(tmp_path / "m.stl"))
    assert isinstance(theirs, StaticMesh)
    for name in ("vertices", "triangles", "active_edges", "node_lo", "node_child_or_first", "triangle_order"):
        np.testing.assert_array_equal(getattr(theirs, name), getattr(ours, name))
    assert len(hull.vertices) >= 4

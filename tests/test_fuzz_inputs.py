"""Issue 27: property-based fuzzing (Hypothesis) of every parser of user input, in-process.

The properties, for any input: the parser either accepts it or refuses it with its own named error (SceneError,
WrenchError, CdrError: a reason naming a field, a key or a position) — never another exception, never an
"internal error"; within bounded time (each example has a deadline) and memory (inputs are bounded by the
limits the parsers enforce first); and what is accepted can be simulated (a spawned body or flock steps and
stays finite).

`make test` runs each property on a few dozen examples, derandomized (the same examples every run: no flakes);
`make fuzz FUZZ_EXAMPLES=5000` runs them longer with fresh random examples (its result goes in the notes).
"""

from __future__ import annotations

import json
import math
import os
import struct

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, assume, event, example, given, settings
from hypothesis import strategies as st

from cgp_core import limits
from cgp_core.editing import EditError
from cgp_core.scene import SceneError, parse_scene, parse_yaml
from cgp_core.world import World
from cgp_sim_ros.wire import cdr

FUZZ_EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "0"))
settings.register_profile("suite", max_examples=40, derandomize=True, deadline=5000, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
settings.register_profile("fuzz", max_examples=max(FUZZ_EXAMPLES, 1), derandomize=False, deadline=20000,
                          print_blob=True, suppress_health_check=list(HealthCheck))
settings.load_profile("fuzz" if FUZZ_EXAMPLES else "suite")

#: numbers at float64's edges and the limits' edges, and ordinary ones
EDGE_FLOATS = st.one_of(
    st.sampled_from([0.0, -0.0, 1.0, -1.0, 1e-308, -1e-308, 5e-324, 1e308, -1e308, 1.7976931348623157e308,
                     math.inf, -math.inf, math.nan, limits.MIN_LENGTH, limits.MAX_LENGTH, limits.MIN_MASS,
                     limits.MAX_MASS, limits.MAX_SPEED, limits.MAX_COORDINATE, 2.0**63, 1e-9]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-10, 10),
    st.integers(-(2**70), 2**70),
)
SCALARS = st.one_of(EDGE_FLOATS, st.booleans(), st.none(), st.text(max_size=20),
                    st.sampled_from(["sphere", "box", "capsule", "particles", "fish", "couzin", "soft", "1e3"]))
KEYS = st.sampled_from(["name", "shape", "radius", "size", "length", "particles", "mass", "density", "position",
                        "orientation", "linear_velocity", "angular_velocity", "friction", "restitution", "fixed",
                        "count", "spawn", "center", "extent", "bounds", "min", "max", "mode", "weights", "rules",
                        "couzin", "neighbors", "k", "neighbor_search", "goal", "model", "world", "bodies",
                        "flocks", "gravity", "substeps", "ground", "x", "named_poses", "tags", "description"])
TREES = st.recursive(SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=5),
                                                        st.dictionaries(KEYS, inner, max_size=6)), max_leaves=30)


def vector(n, elements=EDGE_FLOATS):
    return st.lists(elements, min_size=n, max_size=n)


BODIES = st.fixed_dictionaries(
    {"shape": st.sampled_from(["sphere", "box", "capsule", "particles"])},
    optional={"radius": EDGE_FLOATS, "size": vector(3), "length": EDGE_FLOATS, "mass": EDGE_FLOATS,
              "density": EDGE_FLOATS, "linear_velocity": vector(3), "angular_velocity": vector(3),
              "friction": EDGE_FLOATS, "restitution": EDGE_FLOATS, "fixed": st.booleans(),
              "particles": st.lists(vector(4, st.one_of(EDGE_FLOATS, st.floats(-1, 1))), min_size=1, max_size=8)})


def within(low, high):
    """Numbers in [low, high] (log-uniform for positive ranges spanning decades), the ends included."""
    if low > 0 and high / low > 100:
        inner = st.floats(math.log10(low), math.log10(high)).map(lambda e: min(max(10.0 ** e, low), high))
    else:
        inner = st.floats(low, high)
    return st.one_of(st.sampled_from([low, high]), inner)


LENGTH = within(limits.MIN_LENGTH, limits.MAX_LENGTH)
#: bodies whose every value is inside the limits, the limits' ends included: these must be accepted (or refused
#: for a relation between values, e.g. a density giving a mass outside the range) and then simulate finitely
PLAUSIBLE_BODIES = st.one_of(
    st.fixed_dictionaries({"shape": st.just("sphere"), "radius": LENGTH,
                           "mass": within(limits.MIN_MASS, limits.MAX_MASS)}),
    st.fixed_dictionaries({"shape": st.just("box"), "size": st.lists(LENGTH, min_size=3, max_size=3),
                           "density": within(limits.MIN_DENSITY, limits.MAX_DENSITY)}),
    st.fixed_dictionaries({"shape": st.just("capsule"), "radius": LENGTH, "length": LENGTH,
                           "mass": within(limits.MIN_MASS, limits.MAX_MASS)}),
    st.fixed_dictionaries({"shape": st.just("particles"), "radius": LENGTH,
                           "particles": st.lists(st.tuples(*[within(-limits.MAX_LENGTH, limits.MAX_LENGTH)] * 3,
                                                           within(limits.MIN_MASS, limits.MAX_MASS)).map(list),
                                                 min_size=3, max_size=6)}),
).flatmap(lambda body: st.fixed_dictionaries(
    {}, optional={"linear_velocity": st.lists(within(-limits.MAX_SPEED / 2, limits.MAX_SPEED / 2), min_size=3,
                                              max_size=3),
                  "angular_velocity": st.lists(within(-limits.MAX_SPIN / 2, limits.MAX_SPIN / 2), min_size=3,
                                               max_size=3),
                  "friction": within(0.0, limits.MAX_FRICTION), "restitution": within(0.0, 1.0)}).map(
    lambda extra: {**body, **extra}))
FLOCKS = st.fixed_dictionaries(
    {"count": st.one_of(st.integers(1, 300), st.sampled_from([0, 10**6, 2**63, -1]))},
    optional={"radius": EDGE_FLOATS, "separation_radius": EDGE_FLOATS, "min_speed": EDGE_FLOATS,
              "max_speed": EDGE_FLOATS, "max_acceleration": EDGE_FLOATS, "boid_size": EDGE_FLOATS,
              "spawn": st.fixed_dictionaries({}, optional={"extent": vector(3)}),
              "bounds": st.fixed_dictionaries({}, optional={"min": vector(3), "max": vector(3),
                                                             "mode": st.sampled_from(["soft", "wrap", "none"])}),
              "goal": vector(3), "neighbor_search": st.sampled_from(["grid", "kdtree", "brute"]),
              "rules": st.sampled_from(["reynolds", "couzin"]),
              "couzin": st.fixed_dictionaries({}, optional={"repulsion_radius": EDGE_FLOATS,
                                                            "attraction_width": EDGE_FLOATS,
                                                            "speed": EDGE_FLOATS, "noise": EDGE_FLOATS})})


@pytest.fixture(scope="module")
def world():
    return World.from_scene("zero_g")


def dump(data) -> str:
    """YAML text of ``data`` (PyYAML writes inf / nan / big integers as YAML reads them back)."""
    return yaml.safe_dump(data, default_flow_style=True, width=10**9)


# ---- the scene / spawn parser ------------------------------------------------------------------------------


@given(TREES)
@example({"bodies": [[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]})
@example({"bodies": [{"name": "a", "shape": "box", "size": [1e-308, 1, 1], "mass": 1}]})
@example({"description": "x" * 1_000_000})
def test_any_yaml_tree_is_a_scene_or_a_scene_error(data):
    text = dump(data)
    try:
        parse_scene(text, "fuzz.yaml")
        event("a scene")
    except SceneError as exc:
        assert exc.problems and "internal error" not in str(exc)
        event("refused")


NAMED_POSES = st.lists(st.fixed_dictionaries(
    {"name": st.one_of(st.sampled_from(["a", "b", "ground", "1x"]), SCALARS)},
    optional={"position": st.one_of(vector(3), TREES), "orientation": st.one_of(vector(4), TREES),
              "tags": st.one_of(st.lists(SCALARS, max_size=4), SCALARS), "description": SCALARS,
              "bounds": st.one_of(st.fixed_dictionaries({}, optional={"min": vector(3), "max": vector(3),
                                                                      "radius": EDGE_FLOATS}), TREES)}), max_size=4)


@given(st.one_of(NAMED_POSES, TREES))
def test_any_named_poses_are_poses_or_a_scene_error(poses):
    """Issue 36's ``named_poses`` section: what passes is finite, normalized and bounded as the services send it."""
    try:
        scene = parse_scene(dump({"named_poses": poses}), "fuzz.yaml")
    except SceneError as exc:
        assert exc.problems and "internal error" not in str(exc)
        event("refused")
        return
    event("poses")
    names = [p.name for p in scene.named_poses]
    assert len(names) == len(set(names))
    for pose in scene.named_poses:
        assert np.all(np.isfinite(pose.position)) and np.all(np.abs(pose.position) <= limits.MAX_COORDINATE)
        assert abs(np.linalg.norm(pose.orientation) - 1.0) < 1e-12
        assert all(isinstance(t, str) for t in pose.tags) and isinstance(pose.description, str)
        if pose.bounds is not None:
            assert (pose.bounds.radius is not None and pose.bounds.radius > 0) or \
                bool(np.all(pose.bounds.lower < pose.bounds.upper))


@given(st.text(max_size=400), st.integers(0, 12_000))
@example("", 10_000)
@example("[", 5_000)
def test_any_text_is_yaml_or_a_named_yaml_error(text, depth):
    """Random text, and random text inside a nesting of ``depth`` levels."""
    for candidate in (text, "body: " + "[" * depth + text + "]" * depth, "{a: " * (depth // 4) + text):
        try:
            parse_yaml(candidate, "fuzz")
        except SceneError as exc:
            (problem,) = exc.problems
            assert problem.startswith(("malformed YAML", "line ")), problem


@given(st.one_of(st.builds(lambda b: {"body": b}, BODIES), st.builds(lambda b: {"body": b}, PLAUSIBLE_BODIES),
                 st.builds(lambda f: {"flock": f}, FLOCKS), TREES))
@example({"body": {"shape": "sphere", "radius": 1e308, "mass": 1}})
@example({"body": {"shape": "sphere", "radius": 1, "mass": 1e-308}})
@example({"body": {"shape": "capsule", "radius": 1, "length": 1e308, "mass": 1}})
@example({"flock": {"count": 1_000_000}})
def test_any_spawn_request_is_refused_by_name_or_simulates_finitely(world, entry):
    """Through the node's path (YAML text → parse → World.prepare_spawn → add_spawned), and what is accepted
    steps and stays finite, and is deleted again."""
    name = "fuzzed"
    try:
        far = (0.0, 0.0, 3.0) if isinstance(entry, dict) and "flock" in entry else (3e4,) * 3  # away from zero_g's
        prepared = world.prepare_spawn(parse_yaml(dump(entry), "fuzz"), name=name, taken=set(world.entity_names()),
                                       position=far)
    except (SceneError, EditError) as exc:
        assert "internal error" not in str(exc)
        event("refused")
        return
    event(f"accepted: {prepared.kind}")
    world.add_spawned(prepared)
    try:
        with np.errstate(over="raise", invalid="raise", divide="raise", under="ignore"):  # (subnormals are fine)
            world.step()
        state = world.entity_state(name)
        assert all(np.isfinite(getattr(state, f)).all() for f in ("position", "orientation", "linear_velocity",
                                                                   "angular_velocity"))
        assert world.take_events() == [], "an accepted entity blew up"
        assert np.isfinite(world.body_state.position).all()
    finally:
        world.delete(name)


# ---- mesh files (issue 38) ----------------------------------------------------------------------------------

#: any float64 (and the scene's coordinate range's edges), any int64 index, and plausible ones
MESH_FLOATS = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-3, 3),
                        st.sampled_from([0.0, -0.0, 5e-324, -5e-324, 1e-300, 1e6, -1e6, 1e308, 16.5**200]))
MESH_INDICES = st.one_of(st.integers(-(2**63), 2**63 - 1), st.integers(-8, 24), st.sampled_from([0, -1, 2**63 - 1]))


def mesh_file(vertices, faces, form: str, groups: int, plausible: bool) -> tuple[bytes, str]:
    """A mesh file's bytes and suffix: ``form`` obj | ascii | binary; ``groups``: an OBJ group / an STL ``solid``
    every that many faces; ``plausible``: faces index existing vertices (else as drawn: any int64)."""
    n = max(len(vertices), 1)
    if plausible or form != "obj":
        faces = [[abs(int(i)) % n for i in f] for f in faces]
    if form == "obj":
        lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in vertices]
        for k, f in enumerate(faces):
            if k % groups == 0:
                lines += [f"g g{k}", f"usemtl m{k}"]
            lines.append("f " + " ".join(str(i + 1 if plausible else i) for i in f))
        return ("\n".join(lines) + "\n").encode(), ".obj"
    corners = np.array([[vertices[i] if vertices else (0.0, 0.0, 0.0) for i in f[:3]] for f in faces],
                       dtype=float).reshape(-1, 3, 3)
    if form == "binary":
        with np.errstate(over="ignore"):
            record = np.zeros(len(corners), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
            record["v"] = corners
        return b"\0" * 80 + struct.pack("<I", len(corners)) + record.tobytes(), ".stl"
    lines = []
    for k, facet in enumerate(corners):
        if k % groups == 0:
            lines.append(f"solid s{k}")
        lines += ["facet normal 0 0 1", "outer loop", *(f"vertex {x!r} {y!r} {z!r}" for x, y, z in facet.tolist()),
                  "endloop", "endfacet"]
        if k % groups == groups - 1:
            lines.append(f"endsolid s{k}")
    return ("\n".join(lines) + "\n").encode(), ".stl"


MESH_FILES = st.builds(
    mesh_file,
    st.one_of(st.lists(st.tuples(MESH_FLOATS, MESH_FLOATS, MESH_FLOATS), max_size=16),
              *[st.lists(st.tuples(*[st.floats(-2, 2)] * 3), min_size=4, max_size=16)] * 2),
    st.lists(st.lists(MESH_INDICES, min_size=3, max_size=5), max_size=24),
    st.sampled_from(["obj", "ascii", "binary"]), st.integers(1, 4), st.sampled_from([True, True, False]))


@given(MESH_FILES, st.data())
@example((b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -9223372036854775808\n", ".obj"), None)
@example((b"\0" * 80 + struct.pack("<I", 10**9) + bytes(100), ".stl"), None)
def test_any_mesh_file_is_a_mesh_or_a_named_error(file, draw):
    """Our parsers on any file (and on bytes of it changed at random): arrays whose indices name vertices and
    whose numbers are finite, or a MeshFileError."""
    from cgp_core.collision.meshfile import MeshFileError, parse_mesh

    data, suffix = file
    if draw is not None and data and draw.draw(st.booleans()):
        mutated = bytearray(data)
        for _ in range(draw.draw(st.integers(1, 8))):
            if mutated:
                at = draw.draw(st.integers(0, len(mutated) - 1))
                mutated[at:at + 1] = draw.draw(st.binary(min_size=0, max_size=3))
        data = bytes(mutated)
    try:
        vertices, triangles = parse_mesh(data, suffix[1:], "fuzz" + suffix)
    except MeshFileError as exc:
        assert str(exc).startswith("mesh file fuzz")
        event("refused: " + str(exc).split(": ")[1])  # (not a mesh, empty, too big)
        return
    event("a mesh")
    assert np.isfinite(vertices).all() and len(triangles) > 0
    assert triangles.min() >= 0 and triangles.max() < len(vertices)
    assert (triangles[:, 0] != triangles[:, 1]).all() and (triangles[:, 1] != triangles[:, 2]).all()


@given(MESH_FILES, st.sampled_from(["mesh", "convex"]), st.sampled_from([1.0, 1e6, 1e-9, [1.0, 1.0, 1e-3], 0.5]))
@example((b"v 0 0 0\nv 1e303 0 0\nv 0 1e303 0\nf 1 2 3\n", ".obj"), "mesh", 1e6)
def test_any_mesh_file_spawned_is_refused_by_name_or_simulates_finitely(world, file, shape, scale):
    """A mesh file as a static mesh in the middle of zero_g's flock (its boids query the mesh's BVH) or as a convex
    body: refused with a SceneError naming the key, or built and stepped with every state finite.  `make fuzz`
    runs it with NUMBA_BOUNDSCHECK=1: no compiled kernel may index out of bounds (issue 38: a BVH 327 levels deep
    overflowed its traversal stack in the flock's obstacle query)."""
    import tempfile

    data, suffix = file
    name = "fuzzed_mesh"
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "m" + suffix)
        with open(path, "wb") as out:
            out.write(data)
        entry = {"shape": shape, "mesh": path, "scale": scale}
        entry.update({"fixed": True} if shape == "mesh" else {"mass": 1.0})
        try:
            prepared = world.prepare_spawn({"body": entry}, name=name, taken=set(world.entity_names()),
                                           position=(0.0, 20.0, 10.0) if shape == "mesh" else (3e4, 3e4, 3e4))
        except (SceneError, EditError) as exc:
            assert "internal error" not in str(exc) and str(exc)
            event("refused")
            return
    event(f"accepted: {shape}")
    world.add_spawned(prepared)
    try:
        with np.errstate(over="raise", invalid="raise", divide="raise", under="ignore"):
            world.step()
        assert np.isfinite(world.body_state.position).all() and np.isfinite(world.body_state.orientation).all()
        assert all(np.isfinite(f.positions).all() for f in world.flocks)
    finally:
        world.delete(name)


# ---- the command decoders ----------------------------------------------------------------------------------


def _valid_apply_wrench() -> bytes:
    from cgp_sim_msgs.msg import ApplyWrench
    from rclpy.serialization import serialize_message

    msg = ApplyWrench(body="box")
    msg.wrench.force.x = 1.0
    return serialize_message(msg)


@given(st.binary(max_size=1024), st.data())
def test_random_cdr_bytes_are_a_command_or_a_named_rejection(world, data, draw):
    """Random bytes, and a valid ApplyWrench / WrenchStamped with random bytes and doubles written over it."""
    from cgp_core.wrenches import WrenchError
    from cgp_sim_ros.ros.commands import apply_wrench_command, body_wrench_command

    params = {"max_force": 1e5, "max_torque": 1e5}
    valid = _valid_apply_wrench()
    mutated = bytearray(valid)
    for _ in range(draw.draw(st.integers(0, 6))):
        at = draw.draw(st.integers(0, len(mutated) - 1))
        mutated[at:at + 8] = draw.draw(st.one_of(st.binary(min_size=1, max_size=8),
                                                 st.builds(lambda x: struct.pack("<d", x), EDGE_FLOATS
                                                           .filter(lambda x: isinstance(x, float)))))
    for payload in (data, bytes(mutated), cdr.ENCAPSULATION + data):
        for decode in (lambda p: apply_wrench_command(p, world, params),
                       lambda p: body_wrench_command("box", p, world, params)):
            try:
                command = decode(payload)
            except WrenchError as exc:
                assert exc.field and exc.kind and "internal error" not in str(exc)
                continue
            assert np.isfinite(command.force).all() and np.linalg.norm(command.force) <= 1e5


# ---- the Foxglove client-message path -------------------------------------------------------------------------

JSON_VALUES = st.recursive(st.one_of(st.none(), st.booleans(), EDGE_FLOATS.filter(lambda x: not isinstance(x, int)
                                                                                  or abs(x) < 2**64),
                                     st.text(max_size=10)),
                           lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                   st.dictionaries(st.sampled_from(
                                                       ["body", "wrench", "force", "x", "y", "z", "header",
                                                        "frame_id", "duration", "sec", "nanosec", "point", "q"]),
                                                       inner, max_size=4)), max_leaves=20)


@given(st.one_of(st.binary(max_size=4096), st.builds(lambda v: json.dumps(v).encode(), JSON_VALUES)))
@example(b"[" * 4096)
@example(b'{"wrench": ' * 1000 + b"1" + b"}" * 1000)
def test_foxglove_json_and_requests_are_a_message_or_a_named_rejection(data):
    """Old code: 4,096 bytes of '[' (within the JSON command limit) escaped as a RecursionError."""
    from cgp_sim_msgs.msg import ApplyWrench
    from geometry_msgs.msg import WrenchStamped
    from std_srvs.srv import SetBool

    from cgp_core.wrenches import WrenchError
    from cgp_sim_ros.ros.foxglove_server import _decode_request, _message_from_json

    for msg_type in (ApplyWrench, WrenchStamped):
        try:
            _message_from_json(msg_type, data)
        except WrenchError as exc:
            assert exc.field and exc.kind
    try:
        _decode_request(SetBool.Request, data)
    except Exception as exc:  # noqa: BLE001 - the server turns this into the client's error (see _call)
        assert not isinstance(exc, (RecursionError, MemoryError, SystemError)), exc


# ---- the renderer's marker reader ---------------------------------------------------------------------------


def _valid_marker_array() -> bytes:
    sphere = cdr.marker(cdr.MarkerFields(marker_type=cdr.SPHERE_LIST, ns="flocks/f", id=0, scale=(1, 1, 1),
                                         color=(1, 0, 0, 1), points=np.zeros((3, 3))))
    cube = cdr.marker(cdr.MarkerFields(marker_type=cdr.CUBE, ns="bodies/a", id=0, scale=(1, 2, 3),
                                       color=(0, 1, 0, 1), position=(1, 2, 3)))
    return cdr.marker_array([sphere, cube])


@given(st.binary(max_size=2048), st.data())
@example(cdr.ENCAPSULATION + (2**31 - 1).to_bytes(4, "little") + bytes(300), None)
def test_random_marker_bytes_are_markers_or_a_cdr_error_and_draw_without_error(data, draw):
    from cgp_sim_ros.render.primitives import MarkerSet, extent_points, primitives

    payloads = [data]
    if draw is not None:
        mutated = bytearray(_valid_marker_array())
        for _ in range(draw.draw(st.integers(1, 6))):
            at = draw.draw(st.integers(0, len(mutated) - 1))
            mutated[at:at + 8] = draw.draw(st.one_of(
                st.binary(min_size=1, max_size=8),
                st.builds(lambda x: struct.pack("<d", x), st.floats(allow_nan=True, allow_infinity=True))))
        payloads.append(bytes(mutated))
    for payload in payloads:
        try:
            markers = cdr.read_marker_array(payload)
        except cdr.CdrError as exc:
            assert str(exc)
            continue
        assume(sum(len(m.points) for m in markers) < 100_000)
        marker_set = MarkerSet()
        with np.errstate(all="ignore"):
            marker_set.apply(markers)
            primitives(marker_set)
            extent_points(marker_set)


@pytest.mark.parametrize("size", [2.0 ** 32, 1e300, np.inf, np.nan, -5.0])
def test_a_cube_marker_of_any_size_draws_with_a_bounded_number_of_triangles(size):
    """``make fuzz`` found a cube marker (a bag's bytes) 2³² m long: the renderer cut its faces into 1 m checker
    tiles, 4·10⁹ of them (MemoryError).  A face side is cut into at most MAX_TILES_PER_SIDE tiles, and a side that
    is not finite into one."""
    from cgp_sim_ros.render.primitives import MAX_TILES_PER_SIDE, MarkerSet, primitives

    cube = cdr.marker(cdr.MarkerFields(marker_type=cdr.CUBE, ns="bodies/a", id=0, scale=(size, size, 1.0),
                                       color=(0, 1, 0, 1), position=(0, 0, 0)))
    marker_set = MarkerSet()
    with np.errstate(all="ignore"):
        marker_set.apply(cdr.read_marker_array(cdr.marker_array([cube])))
        drawn = primitives(marker_set)
    assert 12 <= len(drawn.triangles) <= 6 * 2 * MAX_TILES_PER_SIDE ** 2

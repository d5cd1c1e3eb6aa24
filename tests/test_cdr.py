"""cgp_sim_ros.wire.cdr against rclpy: numpy-built CDR bytes are the messages rclpy builds the slow way.

Three independent checks per case:
1. rclpy deserializes the numpy bytes into a message equal, field by field, to the message built from rclpy
   objects (both sides go through rclpy's own (de)serializer, so float32 fields are rounded the same way);
2. the numpy bytes equal, byte for byte, a reference serializer written here from the message classes' field
   types (a generic recursive walk, zero padding), and
3. the reference bytes equal ``rclpy.serialization.serialize_message`` everywhere except at padding bytes
   (rclpy leaves those uninitialised), whose positions the reference serializer reports.
"""

from __future__ import annotations

import importlib
import struct

import numpy as np
import pytest
from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point, Pose, PoseArray
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray, UVCoordinate

from cgp_sim_ros.wire import cdr

SIZES = (0, 1, 7, 1000)
# Lengths 0..5 bytes move everything after the string through every alignment phase; plus non-ASCII UTF-8.
FRAME_IDS = ("", "w", "wo", "wor", "world", "wörld_é", "世界")
STAMPS = (0, 1, 1_700_000_000_123_456_789, -1, -2_000_000_001)


# ------------------------------------------------------------------------------- reference serializer
_PRIMITIVES = {
    "boolean": "?", "octet": "B", "uint8": "B", "char": "B", "int8": "b", "uint16": "H", "int16": "h",
    "uint32": "I", "int32": "i", "uint64": "Q", "int64": "q", "float": "f", "double": "d",
}


def _message_class(type_name: str):
    package, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), name)


class _Reference:
    """Plain CDR (little endian) from an rclpy message, walking ``get_fields_and_field_types()``."""

    def __init__(self):
        self.data = bytearray(b"\x00\x01\x00\x00")
        self.padding = [False] * 4

    def _align(self, n):
        pad = -(len(self.data) - 4) % n
        self.data += bytes(pad)
        self.padding += [True] * pad

    def _put(self, raw):
        self.data += raw
        self.padding += [False] * len(raw)

    def _primitive(self, code, value):
        size = struct.calcsize(code)
        self._align(size)
        self._put(struct.pack("<" + code, value))

    def _value(self, type_str, value):
        if type_str.startswith("sequence<"):
            inner = type_str[len("sequence<"):-1].split(",")[0].strip()
            self._primitive("I", len(value))
            for element in value:
                self._value(inner, element)
        elif type_str.endswith("]"):
            inner, count = type_str[:-1].split("[")
            assert len(value) == int(count)
            for element in value:
                self._value(inner, element)
        elif type_str == "string":
            raw = value.encode("utf-8") + b"\x00"
            self._primitive("I", len(raw))
            self._put(raw)
        elif type_str in _PRIMITIVES:
            if isinstance(value, bytes):
                value = value[0]
            self._primitive(_PRIMITIVES[type_str], value)
        else:
            self.message(value)

    def message(self, msg):
        for name, type_str in msg.get_fields_and_field_types().items():
            self._value(type_str, getattr(msg, name))


def reference_bytes(msg) -> tuple[bytes, np.ndarray]:
    ref = _Reference()
    ref.message(msg)
    return bytes(ref.data), np.array(ref.padding)


def assert_same_message(actual, expected, path="msg"):
    """Field-by-field equality of two rclpy messages (recursive; exact for numbers)."""
    assert type(actual) is type(expected), f"{path}: {type(actual)} != {type(expected)}"
    for name in expected.get_fields_and_field_types():
        a, e = getattr(actual, name), getattr(expected, name)
        where = f"{path}.{name}"
        if hasattr(e, "get_fields_and_field_types"):
            assert_same_message(a, e, where)
        elif isinstance(e, (list, tuple)) and e and hasattr(e[0], "get_fields_and_field_types"):
            assert len(a) == len(e), f"{where}: {len(a)} elements != {len(e)}"
            for i, (x, y) in enumerate(zip(a, e)):
                assert_same_message(x, y, f"{where}[{i}]")
        elif isinstance(e, str):
            assert a == e, f"{where}: {a!r} != {e!r}"
        else:
            assert np.array_equal(np.asarray(a), np.asarray(e)), f"{where}: {a!r} != {e!r}"


def assert_equivalent(numpy_bytes: bytes, slow_msg, zero_padding=True):
    """The three checks of the module docstring (``zero_padding=False``: padding bytes are not compared,
    for bytes assembled from rclpy-serialized parts, whose padding is uninitialised)."""
    msg_type = type(slow_msg)
    expected = deserialize_message(serialize_message(slow_msg), msg_type)
    assert_same_message(deserialize_message(numpy_bytes, msg_type), expected)
    ref, padding = reference_bytes(slow_msg)
    if zero_padding:
        assert numpy_bytes == ref
    rclpy_bytes = np.frombuffer(serialize_message(slow_msg), dtype=np.uint8)
    ours = np.frombuffer(numpy_bytes, dtype=np.uint8)
    assert len(rclpy_bytes) == len(ours)
    assert np.array_equal(ours[~padding], rclpy_bytes[~padding])


# ----------------------------------------------------------------------------------- slow builders
def time_msg(stamp_ns, cls=Time):
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return cls(sec=sec, nanosec=nanosec)


def slow_pose_array(stamp_ns, frame_id, positions, quaternions):
    msg = PoseArray()
    msg.header.stamp = time_msg(stamp_ns)
    msg.header.frame_id = frame_id
    for p, q in zip(positions.tolist(), quaternions.tolist()):
        pose = Pose()
        pose.position.x, pose.position.y, pose.position.z = p
        pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = q
        msg.poses.append(pose)
    return msg


def random_poses(n, seed):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    return rng.normal(scale=10.0, size=(n, 3)), q / np.linalg.norm(q, axis=1, keepdims=True)


# ---------------------------------------------------------------------------------------- PoseArray
@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("frame_id", FRAME_IDS)
def test_pose_array_equals_rclpy(n, frame_id):
    positions, quaternions = random_poses(n, seed=n)
    stamp = STAMPS[n % len(STAMPS)]
    slow = slow_pose_array(stamp, frame_id, positions, quaternions)
    assert_equivalent(cdr.pose_array(stamp, frame_id, positions, quaternions), slow)
    assert_equivalent(cdr.PoseArraySerializer(frame_id).serialize(stamp, positions, quaternions), slow)


def test_pose_array_serializer_reuses_buffer_across_sizes_and_stamps():
    """The fast path stays correct when n changes and when the same buffer is rewritten."""
    serializer = cdr.PoseArraySerializer("map")
    for n, stamp in ((3, 5), (3, 7_000_000_001), (0, 9), (1000, 11), (2, -3)):
        positions, quaternions = random_poses(n, seed=abs(stamp))
        out = serializer.serialize(stamp, positions, quaternions)
        assert_equivalent(out, slow_pose_array(stamp, "map", positions, quaternions))


def test_pose_array_accepts_float32_and_non_contiguous_input():
    positions, quaternions = random_poses(7, seed=1)
    state = np.hstack([positions, quaternions])  # poses as columns of a wider state array
    out = cdr.pose_array(5, "w", state[:, :3], state[:, 3:7].astype(np.float32))
    assert_equivalent(out, slow_pose_array(5, "w", positions, quaternions.astype(np.float32).astype(float)))


@pytest.mark.parametrize("bad, match", [
    (dict(positions=np.zeros((3, 2))), r"positions must have shape \(n, 3\)"),
    (dict(quaternions=np.zeros(4)), r"quaternions must have shape \(n, 4\)"),
    (dict(quaternions=np.zeros((2, 4))), r"positions has 3 rows but quaternions has 2"),
    (dict(frame_id="a\x00b"), "NUL"),
    (dict(stamp_ns=2**80), "stamp_ns"),
])
def test_pose_array_rejects_bad_input_with_a_clear_error(bad, match):
    args = dict(stamp_ns=0, frame_id="w", positions=np.zeros((3, 3)), quaternions=np.zeros((3, 4)))
    args.update(bad)
    with pytest.raises(ValueError, match=match):
        cdr.pose_array(**args)


# ---------------------------------------------------------------------------------------------- Clock
@pytest.mark.parametrize("stamp", STAMPS)
def test_clock_equals_rclpy(stamp):
    assert_equivalent(cdr.clock(stamp), Clock(clock=time_msg(stamp)))


# ------------------------------------------------------------------------------------------- Odometry
def slow_odometry(stamp, frame_id, child, p, q, v, w, pcov, tcov):
    msg = Odometry()
    msg.header.stamp = time_msg(stamp)
    msg.header.frame_id = frame_id
    msg.child_frame_id = child
    pose, twist = msg.pose.pose, msg.twist.twist
    pose.position.x, pose.position.y, pose.position.z = p
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = q
    twist.linear.x, twist.linear.y, twist.linear.z = v
    twist.angular.x, twist.angular.y, twist.angular.z = w
    msg.pose.covariance = np.asarray(pcov, dtype=float).reshape(36)
    msg.twist.covariance = np.asarray(tcov, dtype=float).reshape(36)
    return msg


@pytest.mark.parametrize("frame_id", FRAME_IDS)
def test_odometry_equals_rclpy(frame_id):
    rng = np.random.default_rng(3)
    p, v, w = rng.normal(size=(3, 3))
    q = rng.normal(size=4)
    pcov = rng.normal(size=(6, 6))
    for child in ("", "b", "ball_1", "böx"):
        out = cdr.odometry(123, frame_id, child, p, q, v, w, pose_covariance=pcov)
        assert_equivalent(out, slow_odometry(123, frame_id, child, p, q, v, w, pcov, np.zeros(36)))


@pytest.mark.parametrize("n", (0, 1, 7, 20))
def test_odometry_batch_equals_rclpy_per_body(n):
    rng = np.random.default_rng(n)
    # Child names of every length mod 8, so the messages' paddings differ within one batch.
    children = [("body_" + "x" * (i % 9) + ("é" if i % 4 == 3 else ""))[: 3 + i % 11] for i in range(n)]
    positions, quaternions = random_poses(n, seed=n + 100)
    linear, angular = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    pcov = rng.normal(size=(n, 36))
    tcov = rng.normal(size=36)
    serializer = cdr.OdometryBatchSerializer("world", children)
    for stamp in (17, -5, 1_700_000_000_000_000_001):  # the buffer is reused: later ticks must overwrite
        out = serializer.serialize(stamp, positions, quaternions, linear, angular, pcov, tcov)
        assert len(out) == n
        for i in range(n):
            slow = slow_odometry(stamp, "world", children[i], positions[i], quaternions[i], linear[i],
                                 angular[i], pcov[i], tcov)
            assert_equivalent(out[i], slow)
        positions = positions + 1.0
    one_shot = cdr.odometry_batch(17, "world", children, positions, quaternions, linear, angular)
    assert one_shot == [cdr.odometry(17, "world", c, positions[i], quaternions[i], linear[i], angular[i])
                        for i, c in enumerate(children)]


def test_odometry_batch_rejects_wrong_row_count():
    serializer = cdr.OdometryBatchSerializer("world", ["a", "b"])
    with pytest.raises(ValueError, match=r"linear must have shape \(2, 3\)"):
        serializer.serialize(0, np.zeros((2, 3)), np.zeros((2, 4)), np.zeros((3, 3)), np.zeros((2, 3)))


# --------------------------------------------------------------------------------------------- Marker
def slow_marker(**kw):
    """rclpy Marker from the same keyword arguments as cdr.MarkerFields."""
    msg = Marker()
    msg.header.stamp = time_msg(kw.get("stamp_ns", 0))
    msg.header.frame_id = kw.get("frame_id", "")
    msg.ns = kw.get("ns", "")
    msg.id = kw.get("id", 0)
    msg.type = kw["marker_type"]
    msg.action = kw.get("action", 0)
    p, q = kw.get("position", (0, 0, 0)), kw.get("orientation", (0, 0, 0, 1))
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = map(float, p)
    (msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z,
     msg.pose.orientation.w) = map(float, q)
    msg.scale.x, msg.scale.y, msg.scale.z = map(float, kw.get("scale", (1, 1, 1)))
    msg.color = ColorRGBA(**dict(zip("rgba", map(float, kw.get("color", (1, 1, 1, 1))))))
    msg.lifetime = time_msg(kw.get("lifetime_ns", 0), Duration)
    msg.frame_locked = kw.get("frame_locked", False)
    msg.points = [Point(x=x, y=y, z=z) for x, y, z in np.asarray(kw.get("points", np.zeros((0, 3)))).tolist()]
    msg.colors = [ColorRGBA(r=r, g=g, b=b, a=a)
                  for r, g, b, a in np.asarray(kw.get("colors", np.zeros((0, 4)))).tolist()]
    msg.texture_resource = kw.get("texture_resource", "")
    msg.texture.header.stamp = time_msg(kw.get("texture_stamp_ns", 0))
    msg.texture.header.frame_id = kw.get("texture_frame_id", "")
    msg.texture.format = kw.get("texture_format", "")
    msg.texture.data = bytes(kw.get("texture_data", b""))
    msg.uv_coordinates = [UVCoordinate(u=u, v=v)
                          for u, v in np.asarray(kw.get("uv_coordinates", np.zeros((0, 2)))).tolist()]
    msg.text = kw.get("text", "")
    msg.mesh_resource = kw.get("mesh_resource", "")
    msg.mesh_file.filename = kw.get("mesh_filename", "")
    msg.mesh_file.data = bytes(kw.get("mesh_data", b""))
    msg.mesh_use_embedded_materials = kw.get("mesh_use_embedded_materials", False)
    return msg


def marker_cases():
    """Keyword sets covering every marker kind the node uses, every field, and every alignment phase."""
    rng = np.random.default_rng(7)
    cases = []
    for n in SIZES:
        pts = rng.normal(size=(n, 3))
        cols = rng.uniform(size=(n, 4)).astype(np.float32)
        cases += [
            dict(marker_type=cdr.SPHERE_LIST, ns="flock/fish", id=n, points=pts, colors=cols,
                 scale=(0.1, 0.1, 0.1), color=(0.2, 0.4, 0.6, 0.8)),
            dict(marker_type=cdr.CUBE_LIST, ns="c", id=-n, points=pts),
            dict(marker_type=cdr.POINTS, ns="", points=pts, colors=cols, frame_locked=True),
        ]
    for triangles in (0, 1, 7, 333):
        verts = rng.normal(size=(3 * triangles, 3))
        cases += [
            dict(marker_type=cdr.TRIANGLE_LIST, ns="tri", points=verts,
                 colors=rng.uniform(size=(3 * triangles, 4))),  # per vertex
            dict(marker_type=cdr.TRIANGLE_LIST, ns="tri2", points=verts,
                 colors=rng.uniform(size=(triangles, 4))),  # per triangle
        ]
    for shape in (cdr.CUBE, cdr.SPHERE, cdr.CYLINDER):
        cases.append(dict(marker_type=shape, ns="bodies", id=shape, position=rng.normal(size=3),
                          orientation=rng.normal(size=4), scale=rng.uniform(size=3), color=rng.uniform(size=4),
                          lifetime_ns=1_500_000_000))
    cases += [
        dict(marker_type=cdr.MESH_RESOURCE, ns="meshes", mesh_resource="package://cgp_sim/meshes/fish.dae",
             mesh_use_embedded_materials=True),
        dict(marker_type=cdr.MESH_RESOURCE, ns="m", mesh_resource="embedded://fish", mesh_filename="fish.stl",
             mesh_data=bytes(range(77))),
        dict(marker_type=cdr.TEXT_VIEW_FACING, text="héllo", texture_resource="embedded://tex",
             texture_stamp_ns=-7, texture_frame_id="cam", texture_format="png", texture_data=b"\x89PNG..",
             uv_coordinates=rng.uniform(size=(5, 2)), points=rng.normal(size=(5, 3))),
        dict(marker_type=cdr.ARROW, action=cdr.DELETEALL),
        dict(marker_type=cdr.ARROW, action=cdr.DELETEALL, ns="flock"),
    ]
    return cases


MARKER_CASES = marker_cases()


@pytest.mark.parametrize("case", range(len(MARKER_CASES)))
@pytest.mark.parametrize("frame_id", ("", "wo", "world", "wörld_é"))
def test_marker_equals_rclpy(case, frame_id):
    kw = dict(MARKER_CASES[case], frame_id=frame_id, stamp_ns=STAMPS[case % len(STAMPS)])
    assert_equivalent(cdr.marker(cdr.MarkerFields(**kw)), slow_marker(**kw))


@pytest.mark.parametrize("count", SIZES)
@pytest.mark.parametrize("frame_id", FRAME_IDS)
def test_marker_points_serializer_equals_rclpy_and_marker(count, frame_id):
    """The flocks' fast path: laid out once, points written in place, stamp patched — the same bytes as
    cdr.marker, equivalent to rclpy's serialization, tick after tick, and usable inside a MarkerArray."""
    rng = np.random.default_rng(count)
    for marker_type, ns in ((cdr.TRIANGLE_LIST, "flocks/school"), (cdr.SPHERE_LIST, "f")):
        n = 3 * count if marker_type == cdr.TRIANGLE_LIST else count
        fields = dict(marker_type=marker_type, frame_id=frame_id, ns=ns, id=0, color=(0.95, 0.6, 0.15, 1.0),
                      scale=(0.3, 0.3, 0.3))
        serializer = cdr.MarkerPointsSerializer(n, **fields)
        assert serializer.points.flags.aligned and serializer.points.shape == (n, 3)
        for stamp in STAMPS[:3]:
            points = rng.normal(size=(n, 3))
            serializer.points[:] = points
            data = bytes(serializer.serialize(stamp))
            assert data == cdr.marker(cdr.MarkerFields(points=points, stamp_ns=stamp, **fields))
            assert_equivalent(data, slow_marker(points=points, stamp_ns=stamp, **fields))
        array = cdr.marker_array([cdr.marker(cdr.MarkerFields(marker_type=cdr.CUBE, ns="ground")),
                                  serializer.serialize(7)])
        assert_equivalent(array, MarkerArray(markers=[slow_marker(marker_type=cdr.CUBE, ns="ground"),
                                                      slow_marker(points=points, stamp_ns=7, **fields)]))


@pytest.mark.parametrize("frame_id", FRAME_IDS)
def test_marker_pose_serializer_equals_marker(frame_id):
    """The bodies' fast path: a template patched with stamp and pose, tick after tick, gives marker()'s bytes
    (every shape the node draws, names of every length: every alignment of the pose)."""
    rng = np.random.default_rng(len(frame_id))
    kinds = [dict(marker_type=cdr.SPHERE, scale=(0.6, 0.6, 0.6)), dict(marker_type=cdr.CUBE, scale=(1, 0.5, 2)),
             dict(marker_type=cdr.CYLINDER, scale=(0.4, 0.4, 1.0)),
             dict(marker_type=cdr.SPHERE_LIST, scale=(0.3, 0.3, 0.3), points=rng.normal(size=(4, 3)))]
    for k, kind in enumerate(kinds):
        for ns in ("", "b", "bodies/crate", "bodies/tetromino_"):
            fields = dict(kind, frame_id=frame_id, ns=ns, id=k, color=rng.uniform(size=4))
            serializer = cdr.MarkerPoseSerializer(**fields)
            for stamp in STAMPS[:3]:
                position, orientation = rng.normal(size=3), rng.normal(size=4)
                assert serializer.serialize(stamp, position, orientation) == cdr.marker(cdr.MarkerFields(
                    stamp_ns=stamp, position=position, orientation=orientation, **fields))
    with pytest.raises(ValueError, match="3 \\+ 4 numbers"):
        serializer.serialize(0, (1.0, 2.0), (0.0, 0.0, 0.0, 1.0))


def test_marker_deleteall_is_a_deleteall_marker():
    msg = deserialize_message(cdr.marker_deleteall(5, "world", "flock"), Marker)
    assert (msg.action, msg.ns, msg.header.frame_id) == (Marker.DELETEALL, "flock", "world")


@pytest.mark.parametrize("bad, match", [
    (dict(marker_type=99), "marker_type=99"),
    (dict(action=7), "action=7"),
    (dict(marker_type=cdr.TRIANGLE_LIST, points=np.zeros((4, 3))), "3 points per triangle"),
    (dict(points=np.zeros((4, 3)), colors=np.zeros((3, 4))), "colors has 3 rows"),
    (dict(points=np.zeros((4, 2))), r"points must have shape \(n, 3\)"),
    (dict(scale=(1, 2)), "scale must have 3 components"),
    (dict(id=2**31), "id=2147483648"),
    (dict(ns="a\x00"), "ns="),
])
def test_marker_rejects_bad_input_with_a_clear_error(bad, match):
    kw = dict(marker_type=cdr.SPHERE_LIST)
    kw.update(bad)
    with pytest.raises(ValueError, match=match):
        cdr.marker(cdr.MarkerFields(**kw))


# ---------------------------------------------------------------------------------------- MarkerArray
@pytest.mark.parametrize("count", (0, 1, 2, 9))
@pytest.mark.parametrize("source", ("cdr", "rclpy"))
def test_marker_array_equals_rclpy(count, source):
    """Markers of varied lengths, so that each lands at offsets of both phases (0 and 4 mod 8)."""
    rng = np.random.default_rng(count)
    picks = rng.choice(len(MARKER_CASES), size=count)
    frames = rng.choice(["", "w", "wo", "wor", "worl", "world"], size=count)
    kws = [dict(MARKER_CASES[i], frame_id=str(f), stamp_ns=int(i)) for i, f in zip(picks, frames)]
    slow = MarkerArray(markers=[slow_marker(**kw) for kw in kws])
    if source == "cdr":
        serialized = [cdr.marker(cdr.MarkerFields(**kw)) for kw in kws]
    else:  # rclpy's own bytes, with uninitialised padding, must be accepted too
        serialized = [serialize_message(m) for m in slow.markers]
    assert_equivalent(cdr.marker_array(serialized), slow, zero_padding=source == "cdr")


def test_marker_array_covers_both_phases():
    """Guard for the test above: element start offsets take both values mod 8 in the cases used."""
    phases = set()
    offset = 4
    for kw in MARKER_CASES[:9]:
        offset += -offset % 4
        phases.add(offset % 8)
        offset += len(cdr.marker(cdr.MarkerFields(**kw, frame_id="wor"))) - 4
    assert phases == {0, 4}


def test_marker_array_rejects_non_cdr_le_elements():
    with pytest.raises(ValueError, match=r"markers\[0\] does not start with"):
        cdr.marker_array([b"\x00\x00\x00\x00" + bytes(100)])


# ------------------------------------------------------------------------------- reading MarkerArrays
def _assert_decoded(decoded, msg):
    """A cdr.MarkerData equals the rclpy Marker field by field."""
    stamp = msg.header.stamp
    assert decoded.stamp_ns == stamp.sec * 1_000_000_000 + stamp.nanosec
    assert (decoded.frame_id, decoded.ns, decoded.id, decoded.type, decoded.action) == (
        msg.header.frame_id, msg.ns, msg.id, msg.type, msg.action)
    p, q = msg.pose.position, msg.pose.orientation
    assert decoded.position.tolist() == [p.x, p.y, p.z]
    assert decoded.orientation.tolist() == [q.x, q.y, q.z, q.w]
    assert decoded.scale.tolist() == [msg.scale.x, msg.scale.y, msg.scale.z]
    f32 = np.float32  # colours are float32 on the wire; the rclpy message holds what it was given
    assert decoded.color.tolist() == [f32(msg.color.r), f32(msg.color.g), f32(msg.color.b), f32(msg.color.a)]
    assert decoded.lifetime_ns == msg.lifetime.sec * 1_000_000_000 + msg.lifetime.nanosec
    assert decoded.frame_locked == msg.frame_locked
    assert decoded.points.tolist() == [[pt.x, pt.y, pt.z] for pt in msg.points]
    assert decoded.colors.tolist() == [[f32(c.r), f32(c.g), f32(c.b), f32(c.a)] for c in msg.colors]
    assert (decoded.text, decoded.mesh_resource) == (msg.text, msg.mesh_resource)


@pytest.mark.parametrize("count", (0, 1, 2, 9, len(MARKER_CASES)))
@pytest.mark.parametrize("source", ("cdr", "rclpy"))
def test_read_marker_array_decodes_what_rclpy_serialized(count, source):
    """The renderer's decoder (no rclpy) reads every field of every marker kind, at both alignment phases,
    from our bytes and from rclpy's."""
    rng = np.random.default_rng(100 + count)
    picks = rng.permutation(len(MARKER_CASES))[:count] if count == len(MARKER_CASES) else \
        rng.choice(len(MARKER_CASES), size=count)
    kws = [dict(MARKER_CASES[i], frame_id=str(rng.choice(["", "w", "wor", "world"])),
                stamp_ns=STAMPS[i % len(STAMPS)]) for i in picks]
    slow = MarkerArray(markers=[slow_marker(**kw) for kw in kws])
    data = cdr.marker_array([cdr.marker(cdr.MarkerFields(**kw)) for kw in kws]) if source == "cdr" else \
        serialize_message(slow)
    decoded = cdr.read_marker_array(data)
    assert len(decoded) == count
    for got, msg in zip(decoded, slow.markers):
        _assert_decoded(got, msg)


@pytest.mark.parametrize("bad, match", [
    (b"\x00\x00\x00\x00" + bytes(8), "not little-endian plain CDR"),
    (b"\x00\x01", "too short"),
    (cdr.ENCAPSULATION + struct.pack("<I", 1_000_000) + bytes(200), "claims 1000000 markers"),
])
def test_read_marker_array_rejects_what_is_not_one(bad, match):
    with pytest.raises(cdr.CdrError, match=match):
        cdr.read_marker_array(bad)
    whole = cdr.marker_array([cdr.marker(cdr.MarkerFields(marker_type=cdr.SPHERE_LIST, points=np.ones((10, 3))))])
    with pytest.raises(cdr.CdrError, match="truncated"):
        cdr.read_marker_array(whole[:-40])


# ---------------------------------------------------------------------------------------- TFMessage
def slow_tf_message(stamp_ns, frame_id, children, translations, rotations):
    from geometry_msgs.msg import TransformStamped
    from tf2_msgs.msg import TFMessage

    msg = TFMessage()
    parents = [frame_id] * len(children) if isinstance(frame_id, str) else frame_id
    for parent, child, p, q in zip(parents, children, translations.tolist(), rotations.tolist()):
        t = TransformStamped()
        t.header.stamp = time_msg(stamp_ns)
        t.header.frame_id = parent
        t.child_frame_id = child
        t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = p
        t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w = q
        msg.transforms.append(t)
    return msg


@pytest.mark.parametrize("n", (0, 1, 9))
def test_tf_message_serializer_equals_rclpy(n):
    # child names of every length mod 8, so the transforms' paddings differ within one message
    children = [("body_" + "x" * (i % 9) + ("é" if i % 4 == 3 else ""))[: 3 + i % 11] for i in range(n)]
    serializer = cdr.TFMessageSerializer("world", children)
    translations, rotations = random_poses(n, seed=n + 7)
    for stamp in (17, -5, 1_700_000_000_000_000_001):  # the buffer is reused: later ticks must overwrite
        out = serializer.serialize(stamp, translations, rotations)
        assert_equivalent(out, slow_tf_message(stamp, "world", children, translations, rotations))
        translations = translations + 1.0
    with pytest.raises(ValueError, match=r"rotations must have shape"):
        serializer.serialize(0, translations, np.zeros((n + 1, 4)))


def test_tf_message_serializer_with_a_parent_per_transform_equals_rclpy():
    """A robot's links: each transform with its own parent frame (strings of different lengths)."""
    parents = ["world", "arm/base_link", "arm/l1", "arm/upper_arm_link_é", "arm/w"]
    children = ["arm/base_link", "arm/l1", "arm/upper_arm_link_é", "arm/w", "arm/tool0"]
    serializer = cdr.TFMessageSerializer(parents, children)
    translations, rotations = random_poses(5, seed=3)
    for stamp in (17, 1_700_000_000_000_000_001):
        assert_equivalent(serializer.serialize(stamp, translations, rotations),
                          slow_tf_message(stamp, parents, children, translations, rotations))
    with pytest.raises(ValueError, match=r"4 parent frame ids for 5"):
        cdr.TFMessageSerializer(parents[:4], children)


@pytest.mark.parametrize("k", (0, 1, 6, 7))
def test_joint_state_serializer_equals_rclpy(k):
    from sensor_msgs.msg import JointState

    names = [("joint_" + "x" * (i % 5) + ("é" if i % 3 == 2 else ""))[: 2 + i % 9] for i in range(k)]
    serializer = cdr.JointStateSerializer(names)
    rng = np.random.default_rng(k)
    for stamp in (17, 1_700_000_000_000_000_001):  # the buffer is reused: later ticks must overwrite
        position, velocity, effort = rng.normal(size=(3, k))
        msg = JointState(name=names, position=position.tolist(), velocity=velocity.tolist(), effort=effort.tolist())
        msg.header.stamp = time_msg(stamp)
        out = serializer.serialize(stamp, position, velocity, effort)
        if k:
            assert_equivalent(out, msg)
        else:  # rclpy's buffer is 8 bytes longer (its size estimate aligns the empty float64 sequences; the
            # bytes past the message are uninitialised): the message itself is the same
            assert out == reference_bytes(msg)[0]
            assert_same_message(deserialize_message(out, JointState), msg)
    with pytest.raises(ValueError, match=r"velocity must have shape"):
        serializer.serialize(0, np.zeros(k), np.zeros(k + 1), np.zeros(k))

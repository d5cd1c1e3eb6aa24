"""CDR serialization, built with numpy, of the big and the frequent messages the node publishes (and of our own
``cgp_sim_msgs/FlockStats``).

Why: building ``geometry_msgs/Pose`` objects one by one and serializing them costs several µs per pose in
rclpy (a 10k-pose PoseArray: 75-260 ms on this 2-core machine, ``benchmarks/bench_cdr.py``); the same
message written as CDR bytes from the numpy state costs about half a millisecond.  ``Publisher.publish(bytes)``
sends such bytes as they are, and the bag writer records the very same object: one serialization per message per tick.

Format (what every function here returns):
- A 4-byte encapsulation header ``00 01 00 00`` (plain CDR = XCDR1, little endian), then the body.
- Alignment is counted from the end of the encapsulation header: a primitive of size s (1, 2, 4, 8) starts
  at a body offset that is a multiple of s; the padding bytes before it are written as zeros.
- ``string``: uint32 length *including* the terminating NUL, the UTF-8 bytes, the NUL.
- ``sequence<T>``: uint32 element count, then the elements (the first element is aligned for T only when
  there is one).  Fixed arrays (``float64[36]``) have no count.
- Structures have no alignment of their own: each primitive member is aligned for itself.

All functions are pure and return ``bytes`` (what ``Publisher.publish`` needs: not ``bytearray``).
Times are integer nanoseconds (``stamp_ns``); they are split as ROS does (``sec = floor(ns / 1e9)``,
``nanosec = ns - sec * 1e9``), so negative times keep ``0 <= nanosec < 1e9``.

Equivalence with rclpy's own serializer is proven in ``tests/test_cdr.py``.

Reading (:func:`read_marker_array`): the MarkerArray decoder of the bag renderer, which runs without rclpy.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "ENCAPSULATION",
    "ARROW", "CUBE", "SPHERE", "CYLINDER", "LINE_STRIP", "LINE_LIST", "CUBE_LIST", "SPHERE_LIST", "POINTS",
    "TEXT_VIEW_FACING", "MESH_RESOURCE", "TRIANGLE_LIST", "ARROW_STRIP",
    "ADD", "MODIFY", "DELETE", "DELETEALL",
    "split_stamp",
    "clock",
    "pose_array",
    "PoseArraySerializer",
    "odometry",
    "OdometryBatchSerializer",
    "odometry_batch",
    "TFMessageSerializer",
    "JointStateSerializer",
    "FLOCK_STATS_FIELDS",
    "FlockStatsSerializer",
    "CONTACT_FIELDS",
    "GROUND_ENTITY",
    "ContactsSerializer",
    "MarkerFields",
    "marker",
    "MarkerPointsSerializer",
    "MarkerPoseSerializer",
    "marker_deleteall",
    "marker_array",
    "CdrError",
    "MarkerData",
    "read_marker",
    "read_marker_array",
]

#: Plain CDR, little endian (RTPS representation identifier CDR_LE) + 2 option bytes.
ENCAPSULATION = b"\x00\x01\x00\x00"

# visualization_msgs/Marker constants (same values as the .msg).
ARROW, CUBE, SPHERE, CYLINDER = 0, 1, 2, 3
LINE_STRIP, LINE_LIST, CUBE_LIST, SPHERE_LIST, POINTS = 4, 5, 6, 7, 8
TEXT_VIEW_FACING, MESH_RESOURCE, TRIANGLE_LIST, ARROW_STRIP = 9, 10, 11, 12
ADD, MODIFY, DELETE, DELETEALL = 0, 0, 2, 3
_MARKER_TYPES = frozenset(range(13))
_MARKER_ACTIONS = frozenset((0, 1, 2, 3))  # 1 is deprecated but still a legal value of the field

_NS_PER_S = 1_000_000_000
_ZEROS = bytes(8)
_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1


# --------------------------------------------------------------------------------------------- helpers
def split_stamp(stamp_ns: int) -> tuple[int, int]:
    """``builtin_interfaces/Time`` (sec, nanosec) of an integer nanosecond time."""
    sec, nanosec = divmod(int(stamp_ns), _NS_PER_S)
    if not _INT32_MIN <= sec <= _INT32_MAX:
        raise ValueError(f"stamp_ns={stamp_ns} is outside the int32 seconds range of builtin_interfaces/Time")
    return sec, nanosec


def _pack_stamp(stamp_ns: int, what: str = "stamp_ns") -> bytes:
    try:
        sec, nanosec = divmod(int(stamp_ns), _NS_PER_S)
        return _STAMP.pack(sec, nanosec)
    except (struct.error, TypeError, ValueError):
        raise ValueError(f"{what}={stamp_ns!r} is not an integer nanosecond time within the int32 seconds "
                         f"range of builtin_interfaces/Time") from None


def _encode_string(value: str, what: str) -> bytes:
    """The CDR string body: uint32 length (with NUL), UTF-8 bytes, NUL.  Must start at a 4-aligned offset."""
    if not isinstance(value, str):
        raise TypeError(f"{what} must be a str, got {type(value).__name__}")
    raw = value.encode("utf-8")
    if b"\x00" in raw:
        raise ValueError(f"{what}={value!r} contains a NUL character, which a CDR string cannot carry")
    return _U32.pack(len(raw) + 1) + raw + b"\x00"


def _float_rows(array, columns: int, what: str, dtype=np.float64) -> np.ndarray:
    """``array`` as a C-contiguous little-endian (n, columns) array of ``dtype`` (no copy when it already is)."""
    arr = np.asarray(array)
    if arr.ndim != 2 or arr.shape[1] != columns:
        raise ValueError(f"{what} must have shape (n, {columns}), got {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number) or np.issubdtype(arr.dtype, np.complexfloating):
        raise TypeError(f"{what} must be a real numeric array, got dtype {arr.dtype}")
    return np.ascontiguousarray(arr, dtype=np.dtype(dtype).newbyteorder("<"))


def _floats(value, size: int, what: str):
    """``value`` (a sequence or a numpy vector of ``size`` numbers) as a list of Python floats."""
    try:
        values = [float(x) for x in value]
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be {size} numbers, got {value!r}") from None
    if len(values) != size:
        raise ValueError(f"{what} must have {size} components, got {len(values)}")
    return values


def _check_int32(value: int, what: str) -> int:
    value = int(value)
    if not _INT32_MIN <= value <= _INT32_MAX:
        raise ValueError(f"{what}={value} does not fit in an int32")
    return value


class _Writer:
    """Collects CDR pieces and tracks the body offset (relative to the end of the encapsulation header)."""

    __slots__ = ("parts", "pos")

    def __init__(self, parts: list | None = None, pos: int = 0) -> None:
        self.parts: list = [ENCAPSULATION] if parts is None else parts
        self.pos = pos

    def align(self, n: int) -> None:
        pad = -self.pos % n
        if pad:
            self.parts.append(_ZEROS[:pad])
            self.pos += pad

    def raw(self, data) -> None:
        self.parts.append(data)
        self.pos += len(data)

    def string(self, encoded: bytes) -> None:
        """Append an already :func:`_encode_string`-encoded string (aligns the length to 4)."""
        self.align(4)
        self.parts.append(encoded)
        self.pos += len(encoded)

    def sequence(self, count: int, element_align: int, payload) -> None:
        """uint32 count, then the elements' bytes (``payload``, a bytes-like of ``nbytes`` size)."""
        self.align(4)
        self.parts.append(_U32.pack(count))
        self.pos += 4
        if count:
            self.align(element_align)
            self.parts.append(payload)
            self.pos += memoryview(payload).nbytes

    def header(self, stamp_ns: int, frame_id: str) -> None:
        self.raw(_pack_stamp(stamp_ns))
        self.string(_encode_string(frame_id, "frame_id"))

    def getvalue(self) -> bytes:
        return b"".join(self.parts)


# ----------------------------------------------------------------------------------------------- Clock
def clock(stamp_ns: int) -> bytes:
    """``rosgraph_msgs/Clock`` with ``clock = stamp_ns``."""
    return ENCAPSULATION + _pack_stamp(stamp_ns)


# ------------------------------------------------------------------------------------------- PoseArray
def _pose_array_prefix(stamp: bytes, frame: bytes, count: int) -> bytes:
    """Encapsulation, header and sequence count, with the padding that puts the first pose on 8 bytes."""
    # Body offsets: stamp [0, 8), frame id string [8, 8 + len(frame)), then the count on 4, poses on 8.
    pos = 8 + len(frame)
    pad4 = -pos % 4
    pos += pad4 + 4
    pad8 = (-pos % 8) if count else 0
    return b"".join((ENCAPSULATION, stamp, frame, _ZEROS[:pad4], _U32.pack(count), _ZEROS[:pad8]))


def pose_array(stamp_ns: int, frame_id: str, positions, quaternions) -> bytes:
    """``geometry_msgs/PoseArray`` of n poses.

    Args:
        stamp_ns: header stamp, integer nanoseconds.
        frame_id: header frame id.
        positions: (n, 3) positions (any real dtype; written as float64).
        quaternions: (n, 4) orientations (x, y, z, w).
    """
    pos = _float_rows(positions, 3, "positions")
    quat = _float_rows(quaternions, 4, "quaternions")
    if len(pos) != len(quat):
        raise ValueError(f"positions has {len(pos)} rows but quaternions has {len(quat)}")
    n = len(pos)
    prefix = _pose_array_prefix(_pack_stamp(stamp_ns), _encode_string(frame_id, "frame_id"), n)
    if n == 0:
        return prefix
    # One (n, 7) block written straight into the output buffer: a Pose is 7 contiguous float64.
    out = bytearray(len(prefix) + 56 * n)
    out[: len(prefix)] = prefix
    block = np.frombuffer(out, dtype="<f8", count=7 * n, offset=len(prefix)).reshape(n, 7)
    block[:, :3] = pos
    block[:, 3:] = quat
    return bytes(out)


class PoseArraySerializer:
    """Reusable-buffer fast path for :func:`pose_array` (same bytes).

    Keeps one output buffer per (frame id, n) and rewrites only the stamp and the poses, so a tick costs two
    strided copies into the buffer and one copy out of it (``bytes``, which the publisher and the bag writer
    may keep).  One instance per topic; not thread-safe.
    """

    def __init__(self, frame_id: str) -> None:
        self._frame = _encode_string(frame_id, "frame_id")
        self._count = -1
        self._buffer = np.zeros(0, dtype=np.uint8)
        self._prefix_len = 0
        self._block = np.zeros((0, 7))

    def _resize(self, n: int) -> None:
        prefix = _pose_array_prefix(bytes(8), self._frame, n)
        self._buffer = np.zeros(len(prefix) + 56 * n, dtype=np.uint8)
        self._buffer[: len(prefix)] = np.frombuffer(prefix, dtype=np.uint8)
        self._prefix_len = len(prefix)
        # (n, 7) float64 view of the poses inside the buffer (the offset need not be 8-aligned in memory).
        self._block = self._buffer[len(prefix):].view("<f8").reshape(n, 7)
        self._count = n

    def serialize(self, stamp_ns: int, positions, quaternions) -> bytes:
        pos = np.asarray(positions)
        quat = np.asarray(quaternions)
        if pos.ndim != 2 or pos.shape[1] != 3:
            raise ValueError(f"positions must have shape (n, 3), got {pos.shape}")
        if quat.ndim != 2 or quat.shape[1] != 4:
            raise ValueError(f"quaternions must have shape (n, 4), got {quat.shape}")
        if len(pos) != len(quat):
            raise ValueError(f"positions has {len(pos)} rows but quaternions has {len(quat)}")
        if len(pos) != self._count:
            self._resize(len(pos))
        self._buffer[4:12] = np.frombuffer(_pack_stamp(stamp_ns), dtype=np.uint8)
        self._block[:, :3] = pos
        self._block[:, 3:] = quat
        return self._buffer.tobytes()


# -------------------------------------------------------------------------------------------- Odometry
# After the two strings everything is float64: pose (7), pose covariance (36), twist (6), twist covariance (36).
_ODOM_FLOATS = 85
_ODOM_POS, _ODOM_QUAT, _ODOM_PCOV = slice(0, 3), slice(3, 7), slice(7, 43)
_ODOM_LIN, _ODOM_ANG, _ODOM_TCOV = slice(43, 46), slice(46, 49), slice(49, 85)


def _odometry_prefix(stamp: bytes, frame: bytes, child: bytes) -> bytes:
    """Encapsulation, header, child frame id and the padding that puts the pose on 8 bytes."""
    pos = 8 + len(frame)
    pad_child = -pos % 4
    pos += pad_child + len(child)
    pad_pose = -pos % 8
    return b"".join((ENCAPSULATION, stamp, frame, _ZEROS[:pad_child], child, _ZEROS[:pad_pose]))


def _covariance_rows(cov, n: int, what: str) -> np.ndarray:
    """(n, 36) from None (zeros), a (36,) / (6, 6) matrix shared by all, or (n, 36) / (n, 6, 6)."""
    if cov is None:
        return np.zeros((n, 36))
    arr = np.asarray(cov, dtype=np.float64)
    if arr.shape in ((36,), (6, 6)):
        return np.broadcast_to(arr.reshape(36), (n, 36))
    if arr.shape in ((n, 36), (n, 6, 6)):
        return arr.reshape(n, 36)
    raise ValueError(f"{what} must have shape (36,), (6, 6), ({n}, 36) or ({n}, 6, 6), got {arr.shape}")


def odometry(stamp_ns: int, frame_id: str, child_frame_id: str, position, orientation, linear, angular,
             pose_covariance=None, twist_covariance=None) -> bytes:
    """``nav_msgs/Odometry`` of one body: pose in ``frame_id``, twist in ``child_frame_id`` axes.

    Args:
        position: (3,); orientation: (4,) quaternion (x, y, z, w); linear, angular: (3,) velocities.
        pose_covariance, twist_covariance: row-major (36,) or (6, 6); None = zeros.
    """
    values = np.empty(_ODOM_FLOATS)
    values[_ODOM_POS] = _floats(position, 3, "position")
    values[_ODOM_QUAT] = _floats(orientation, 4, "orientation")
    values[_ODOM_PCOV] = _covariance_rows(pose_covariance, 1, "pose_covariance")[0]
    values[_ODOM_LIN] = _floats(linear, 3, "linear")
    values[_ODOM_ANG] = _floats(angular, 3, "angular")
    values[_ODOM_TCOV] = _covariance_rows(twist_covariance, 1, "twist_covariance")[0]
    prefix = _odometry_prefix(_pack_stamp(stamp_ns), _encode_string(frame_id, "frame_id"),
                              _encode_string(child_frame_id, "child_frame_id"))
    return prefix + values.astype("<f8", copy=False).tobytes()


class OdometryBatchSerializer:
    """``nav_msgs/Odometry`` for n bodies per tick, one message per body, built in one buffer.

    The n messages live back to back in one byte buffer laid out once (header frame and child frame ids do not
    change): each message starts at a memory offset chosen so that its 85 floats are 8-byte aligned, so one
    float64 view of the whole buffer addresses every message's pose/twist block by fancy indexing.  A tick
    writes the stamps and the (n, 85) values with a few vectorized assignments, then slices out n ``bytes``.
    Not thread-safe.
    """

    def __init__(self, frame_id: str, child_frame_ids: Sequence[str]) -> None:
        frame = _encode_string(frame_id, "frame_id")
        prefixes = [_odometry_prefix(bytes(8), frame, _encode_string(c, f"child_frame_ids[{i}]"))
                    for i, c in enumerate(child_frame_ids)]
        self.count = len(prefixes)
        starts, float_rows, offset = [], [], 0
        for prefix in prefixes:
            # Every prefix length is 4 mod 8 (the pose is 8-aligned after the 4-byte encapsulation), so a
            # message starting at 4 mod 8 in memory has its floats 8-aligned in memory.
            offset += (4 - offset) % 8
            starts.append(offset)
            assert (offset + len(prefix)) % 8 == 0, "Odometry floats must be 8-aligned in the buffer"
            float_rows.append((offset + len(prefix)) // 8)
            offset += len(prefix) + 8 * _ODOM_FLOATS
        total = offset + (-offset % 8)
        self._buffer = np.zeros(total, dtype=np.uint8)
        for start, prefix in zip(starts, prefixes):
            self._buffer[start:start + len(prefix)] = np.frombuffer(prefix, dtype=np.uint8)
        self._floats = self._buffer.view("<f8")
        self._words = self._buffer.view("<u4")
        self._bounds = [(s, s + len(p) + 8 * _ODOM_FLOATS) for s, p in zip(starts, prefixes)]
        rows = np.asarray(float_rows, dtype=np.intp)
        self._sec_index = (np.asarray(starts, dtype=np.intp) + 4) // 4  # stamp at byte 4 of each message
        self._float_index = rows[:, None] + np.arange(_ODOM_FLOATS)  # (n, 85)
        self._view = memoryview(self._buffer)

    def serialize(self, stamp_ns: int, positions, orientations, linear, angular,
                  pose_covariance=None, twist_covariance=None) -> list[bytes]:
        """One Odometry per body, in the order of ``child_frame_ids``.

        Args:
            positions (n, 3), orientations (n, 4) (x, y, z, w), linear (n, 3), angular (n, 3) (body axes);
            covariances: None (zeros), a shared (36,) / (6, 6), or per body (n, 36) / (n, 6, 6).
        """
        n = self.count
        sec, nanosec = split_stamp(stamp_ns)
        values = np.empty((n, _ODOM_FLOATS))
        for block, array, width, what in ((_ODOM_POS, positions, 3, "positions"),
                                          (_ODOM_QUAT, orientations, 4, "orientations"),
                                          (_ODOM_LIN, linear, 3, "linear"), (_ODOM_ANG, angular, 3, "angular")):
            arr = np.asarray(array)
            if arr.shape != (n, width):
                raise ValueError(f"{what} must have shape ({n}, {width}), got {arr.shape}")
            values[:, block] = arr
        values[:, _ODOM_PCOV] = _covariance_rows(pose_covariance, n, "pose_covariance")
        values[:, _ODOM_TCOV] = _covariance_rows(twist_covariance, n, "twist_covariance")
        self._words[self._sec_index] = sec & 0xFFFFFFFF
        self._words[self._sec_index + 1] = nanosec
        self._floats[self._float_index] = values
        view = self._view
        return [bytes(view[a:b]) for a, b in self._bounds]


def odometry_batch(stamp_ns: int, frame_id: str, child_frame_ids: Sequence[str], positions, orientations,
                   linear, angular, pose_covariance=None, twist_covariance=None) -> list[bytes]:
    """One-shot :class:`OdometryBatchSerializer` (keep a serializer per node for the per-tick path)."""
    return OdometryBatchSerializer(frame_id, child_frame_ids).serialize(
        stamp_ns, positions, orientations, linear, angular, pose_covariance, twist_covariance)


# ------------------------------------------------------------------------------------------- TFMessage
class TFMessageSerializer:
    """``tf2_msgs/TFMessage`` of n ``geometry_msgs/TransformStamped`` (``frame_id`` → ``child_frame_ids[i]``;
    ``frame_id`` one id for all or a sequence of n, one per transform) per tick, all with one stamp.

    The message is laid out once (the frame ids do not change): ``uint32 n``, then per transform the stamp,
    the two strings and 7 float64 (translation, rotation x y z w) 8-aligned.  It is kept at memory offset 4 of
    a buffer so that every float64 is 8-aligned in memory too, and a tick writes the stamps and the (n, 7)
    values with two vectorized assignments.  Not thread-safe.
    """

    def __init__(self, frame_id: str | Sequence[str], child_frame_ids: Sequence[str]) -> None:
        # one parent for all (the bodies: ``world``) or one per transform (a robot's links: their parent links)
        parents = [frame_id] * len(child_frame_ids) if isinstance(frame_id, str) else list(frame_id)
        if len(parents) != len(child_frame_ids):
            raise ValueError(f"{len(parents)} parent frame ids for {len(child_frame_ids)} child frame ids")
        encoded = {parent: _encode_string(parent, "frame_id") for parent in set(parents)}
        writer = _Writer()
        writer.raw(_U32.pack(len(child_frame_ids)))
        stamps, floats = [], []
        for i, child in enumerate(child_frame_ids):
            stamps.append(writer.pos)  # TransformStamped starts with header.stamp: 4-aligned after a string
            writer.raw(bytes(8))
            writer.string(encoded[parents[i]])
            writer.string(_encode_string(child, f"child_frame_ids[{i}]"))
            writer.align(8)
            floats.append(writer.pos)
            writer.raw(bytes(56))
        template = writer.getvalue()  # encapsulation + body
        self.count = len(child_frame_ids)
        self._size = len(template)
        self._buffer = np.zeros(4 + self._size + (-(4 + self._size) % 8), dtype=np.uint8)
        self._buffer[4:4 + self._size] = np.frombuffer(template, dtype=np.uint8)
        # body offset b is at memory offset 4 (buffer padding) + 4 (encapsulation) + b
        self._sec_index = (8 + np.asarray(stamps, dtype=np.intp)) // 4
        self._float_index = ((8 + np.asarray(floats, dtype=np.intp)) // 8)[:, None] + np.arange(7)
        self._words = self._buffer.view("<u4")
        self._floats = self._buffer.view("<f8")
        self._view = memoryview(self._buffer)[4:4 + self._size]

    def serialize(self, stamp_ns: int, translations, rotations) -> bytes:
        """``translations (n, 3)``, ``rotations (n, 4)`` (x, y, z, w), in the order of ``child_frame_ids``."""
        n = self.count
        sec, nanosec = split_stamp(stamp_ns)
        values = np.empty((n, 7))
        for block, array, width, what in ((slice(0, 3), translations, 3, "translations"),
                                          (slice(3, 7), rotations, 4, "rotations")):
            arr = np.asarray(array)
            if arr.shape != (n, width):
                raise ValueError(f"{what} must have shape ({n}, {width}), got {arr.shape}")
            values[:, block] = arr
        self._words[self._sec_index] = sec & 0xFFFFFFFF
        self._words[self._sec_index + 1] = nanosec
        self._floats[self._float_index] = values
        return bytes(self._view)


# ------------------------------------------------------------------------------------------ JointState
class JointStateSerializer:
    """``sensor_msgs/JointState`` of a robot's k joints (names fixed), one per tick: header, the k names, then
    position, velocity and effort, each a sequence of k float64.  Laid out once (the names do not change); kept
    at memory offset 4 of its buffer so that the float64 are 8-aligned in memory too, and a tick writes the stamp
    and the (3, k) values with two assignments.  Not thread-safe."""

    def __init__(self, names: Sequence[str], frame_id: str = "") -> None:
        writer = _Writer()
        writer.header(0, frame_id)
        writer.align(4)
        writer.raw(_U32.pack(len(names)))
        for i, name in enumerate(names):
            writer.string(_encode_string(name, f"names[{i}]"))
        self.count = k = len(names)
        starts = []
        for _ in range(3):  # position, velocity, effort
            writer.align(4)
            writer.raw(_U32.pack(k))
            if k:  # an empty sequence has no elements to align (rclpy's buffer is longer: its size estimate
                writer.align(8)  # aligns them anyway, and the bytes past the message are left uninitialised)
            starts.append(writer.pos)
            writer.raw(bytes(8 * k))
        template = writer.getvalue()
        self._size = len(template)
        self._buffer = np.zeros(4 + self._size + (-(4 + self._size) % 8), dtype=np.uint8)
        self._buffer[4:4 + self._size] = np.frombuffer(template, dtype=np.uint8)
        # body offset b is at memory offset 4 (buffer padding) + 4 (encapsulation) + b
        self._words = self._buffer.view("<u4")
        self._stamp = slice(2, 4)
        self._value_index = ((8 + np.asarray(starts, dtype=np.intp)) // 8)[:, None] + np.arange(k)
        self._floats = self._buffer.view("<f8")
        self._view = memoryview(self._buffer)[4:4 + self._size]

    def serialize(self, stamp_ns: int, position, velocity, effort) -> bytes:
        """``position``, ``velocity``, ``effort``: (k,) each, in the order of the names."""
        sec, nanosec = split_stamp(stamp_ns)
        values = np.empty((3, self.count))
        for row, (array, what) in enumerate(((position, "position"), (velocity, "velocity"), (effort, "effort"))):
            arr = np.asarray(array, dtype=np.float64)
            if arr.shape != (self.count,):
                raise ValueError(f"{what} must have shape ({self.count},), got {arr.shape}")
            values[row] = arr
        self._words[self._stamp] = (sec & 0xFFFFFFFF, nanosec)
        self._floats[self._value_index] = values
        return bytes(self._view)


# ------------------------------------------------------------------------------------------ FlockStats
#: ``cgp_sim_msgs/FlockStats`` after its header and ``count``: these float64, in the order of the .msg
FLOCK_STATS_FIELDS = ("polarization", "milling", "centroid_x", "centroid_y", "centroid_z", "radius_of_gyration",
                      "mean_nearest_neighbor_distance", "mean_speed", "min_speed", "max_speed")


class FlockStatsSerializer:
    """``cgp_sim_msgs/FlockStats`` (a flock's order parameters, :mod:`cgp_core.boids.order`), one per flock per
    tick.  Laid out once (the frame id does not change): header, ``uint32 count``, then the 10 float64 of
    :data:`FLOCK_STATS_FIELDS` 8-aligned; kept at memory offset 4 of its buffer so that the floats are 8-aligned in
    memory too, and a tick writes the stamp, the count and the (10,) values with three assignments.  Not
    thread-safe."""

    def __init__(self, frame_id: str) -> None:
        writer = _Writer()
        writer.header(0, frame_id)
        writer.align(4)
        count = writer.pos
        writer.raw(bytes(4))
        writer.align(8)
        floats = writer.pos
        writer.raw(bytes(8 * len(FLOCK_STATS_FIELDS)))
        template = writer.getvalue()
        self._size = len(template)
        self._buffer = np.zeros(4 + self._size, dtype=np.uint8)
        self._buffer[4:] = np.frombuffer(template, dtype=np.uint8)
        # body offset b is at memory offset 4 (buffer padding) + 4 (encapsulation) + b
        self._words = self._buffer.view("<u4")
        self._stamp = slice(2, 4)
        self._count = (8 + count) // 4
        first = (8 + floats) // 8
        self._values = self._buffer.view("<f8")[first:first + len(FLOCK_STATS_FIELDS)]
        self._view = memoryview(self._buffer)[4:]

    def serialize(self, stamp_ns: int, count: int, values) -> bytes:
        """``count`` boids and ``values`` (10,): the order parameters in the order of :data:`FLOCK_STATS_FIELDS`."""
        sec, nanosec = split_stamp(stamp_ns)
        if not 0 <= int(count) < 2**32:
            raise ValueError(f"count={count} does not fit in a uint32")
        self._words[self._stamp] = (sec & 0xFFFFFFFF, nanosec)
        self._words[self._count] = int(count)
        self._values[:] = values
        return bytes(self._view)


# -------------------------------------------------------------------------------------------- Contacts
#: ``cgp_sim_msgs/Contact`` after its two strings: these float64, in the order of the .msg
CONTACT_FIELDS = ("position_x", "position_y", "position_z", "normal_x", "normal_y", "normal_z", "separation",
                  "normal_impulse", "friction_impulse_x", "friction_impulse_y", "friction_impulse_z")
#: the entity name of the ground plane in ``cgp_sim_msgs/Contact`` (side A of its contacts); reserved: no body or
#: flock may take it (cgp_core.scene.GROUND_NAME, the same text: not imported, this module stays light)
GROUND_ENTITY = "ground"


class ContactsSerializer:
    """``cgp_sim_msgs/Contacts`` (the tick's :class:`cgp_core.solver.report.ContactReport`), one per tick.

    A ``Contact`` is two strings (the entities' names) and 11 float64 (:data:`CONTACT_FIELDS`), an
    ``EntityWrench`` a string and 6 float64; the floats are 8-aligned after the strings, so every element after
    the first of a sequence starts 8-aligned and its bytes before the floats depend only on its names.  Those
    are encoded once per name pair (and start phase) and kept; a tick appends, per contact, that prefix and a
    view of its 88 bytes of floats.  Entities are body indices into ``entity_names``; −1 is the ground
    (:data:`GROUND_ENTITY`).  Not thread-safe.
    """

    _PREFIXES_KEPT = 100_000  # name pairs remembered (bounded: a long run with many spawned bodies starts over)

    def __init__(self, frame_id: str, entity_names: Sequence[str]) -> None:
        self._frame = _encode_string(frame_id, "frame_id")
        # index i → the encoded name of body i; index −1 (the last) → the ground
        self._names = [_encode_string(n, f"entity_names[{i}]") for i, n in enumerate(entity_names)]
        self._names.append(_encode_string(GROUND_ENTITY, "ground"))
        self._prefixes: dict[tuple, bytes] = {}

    def _prefix(self, names: tuple, phase: int) -> bytes:
        """The strings of ``names`` (entity indices) and the padding that puts the floats after them on 8, for
        an element starting at body offset ≡ ``phase`` (mod 8)."""
        key = (names, phase)
        prefix = self._prefixes.get(key)
        if prefix is None:
            if len(self._prefixes) >= self._PREFIXES_KEPT:
                self._prefixes.clear()
            w = _Writer([], phase)
            for i in names:
                w.string(self._names[i])
            w.align(8)
            prefix = self._prefixes[key] = b"".join(w.parts)
        return prefix

    def serialize(self, stamp_ns: int, duration: float, body_a, body_b, values, body, wrenches) -> bytes:
        """``body_a``, ``body_b`` (k,) entity indices (−1: the ground), ``values (k, 11)`` (:data:`CONTACT_FIELDS`),
        ``body (b,)`` the bodies with a wrench, ``wrenches (b, 6)`` their force and torque."""
        contacts = _float_rows(values, len(CONTACT_FIELDS), "values")
        sums = _float_rows(wrenches, 6, "wrenches")
        a, b, owner = (np.asarray(x, dtype=np.int64).tolist() for x in (body_a, body_b, body))
        if not len(a) == len(b) == len(contacts) or len(owner) != len(sums):
            raise ValueError(f"{len(a)} body_a, {len(b)} body_b and {len(contacts)} value rows; {len(owner)} bodies "
                             f"and {len(sums)} wrenches: each pair must match")
        w = _Writer()
        w.raw(_pack_stamp(stamp_ns))
        w.string(self._frame)
        w.align(8)
        w.raw(struct.pack("<dI", float(duration), len(a)))
        parts, pos = w.parts, w.pos
        rows = memoryview(contacts.tobytes())
        for k in range(len(a)):
            prefix = self._prefix((a[k], b[k]), pos % 8)
            parts.append(prefix)
            parts.append(rows[88 * k:88 * k + 88])
            pos += len(prefix) + 88
        w.pos = pos
        w.align(4)
        w.raw(_U32.pack(len(owner)))
        pos = w.pos
        rows = memoryview(sums.tobytes())
        for k in range(len(owner)):
            prefix = self._prefix((owner[k],), pos % 8)
            parts.append(prefix)
            parts.append(rows[48 * k:48 * k + 48])
            pos += len(prefix) + 48
        return b"".join(parts)


# ---------------------------------------------------------------------------------------------- Marker
def _optional_bytes(value, what: str) -> bytes:
    if value is None:
        return b""
    if isinstance(value, np.ndarray):
        return np.ascontiguousarray(value, dtype=np.uint8).tobytes()
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value)
    raise TypeError(f"{what} must be bytes or a uint8 array, got {type(value).__name__}")


@dataclass(frozen=True)
class MarkerFields:
    """Every field of a ``visualization_msgs/Marker``, for :func:`marker` (defaults = the message defaults,
    except a white opaque ``color``, unit ``scale`` and identity ``orientation``, which rviz needs to draw
    anything).  The nested messages are flattened: ``header`` → ``stamp_ns`` / ``frame_id``, ``pose`` →
    ``position`` / ``orientation``, ``texture`` (sensor_msgs/CompressedImage) → ``texture_*``, ``mesh_file``
    (visualization_msgs/MeshFile) → ``mesh_filename`` / ``mesh_data``.

    Array fields (numpy, any real dtype):
        points: (N, 3) -> ``points`` (float64).  TRIANGLE_LIST needs N % 3 == 0.
        colors: (N, 4) RGBA -> ``colors`` (float32); N must be 0 or len(points) (TRIANGLE_LIST also accepts
            one color per triangle, as rviz does).
        uv_coordinates: (N, 2) -> ``uv_coordinates`` (float32).
    ``texture_data`` and ``mesh_data``: bytes or a uint8 array.  Checked by :func:`marker`, not here.
    """

    marker_type: int
    stamp_ns: int = 0
    frame_id: str = ""
    ns: str = ""
    id: int = 0  # noqa: A003 - the message's field name
    action: int = ADD
    position: Sequence[float] = (0.0, 0.0, 0.0)
    orientation: Sequence[float] = (0.0, 0.0, 0.0, 1.0)
    scale: Sequence[float] = (1.0, 1.0, 1.0)
    color: Sequence[float] = (1.0, 1.0, 1.0, 1.0)
    lifetime_ns: int = 0
    frame_locked: bool = False
    points: object = None
    colors: object = None
    texture_resource: str = ""
    texture_stamp_ns: int = 0
    texture_frame_id: str = ""
    texture_format: str = ""
    texture_data: object = None
    uv_coordinates: object = None
    text: str = ""
    mesh_resource: str = ""
    mesh_filename: str = ""
    mesh_data: object = None
    mesh_use_embedded_materials: bool = False


def marker(fields: MarkerFields) -> bytes:
    """``visualization_msgs/Marker`` with every field of ``fields``; a ``ValueError`` / ``TypeError`` naming the
    field for a value the message cannot carry."""
    f = fields
    marker_type = int(f.marker_type)
    if marker_type not in _MARKER_TYPES:
        raise ValueError(f"marker_type={marker_type} is not a visualization_msgs/Marker type (0..12)")
    if int(f.action) not in _MARKER_ACTIONS:
        raise ValueError(f"action={f.action} is not a visualization_msgs/Marker action (0 ADD, 2 DELETE, "
                         f"3 DELETEALL)")
    pts = _float_rows(f.points, 3, "points") if f.points is not None else _NO_POINTS
    cols = _float_rows(f.colors, 4, "colors", np.float32) if f.colors is not None else _NO_COLORS
    if marker_type == TRIANGLE_LIST and len(pts) % 3:
        raise ValueError(f"a TRIANGLE_LIST marker needs 3 points per triangle, got {len(pts)} points")
    allowed_colors = {0, len(pts)} | ({len(pts) // 3} if marker_type == TRIANGLE_LIST else set())
    if len(cols) not in allowed_colors:
        raise ValueError(f"colors has {len(cols)} rows; it must be empty or match the {len(pts)} points"
                         + (" (or the triangles)" if marker_type == TRIANGLE_LIST else ""))

    # Everything up to ``colors`` is packed directly (the per-tick path: ~10 markers per tick); offsets are
    # body offsets (after the encapsulation header).
    frame = _encode_string(f.frame_id, "frame_id")
    ns_raw = _encode_string(f.ns, "ns")
    pos = 8 + len(frame)
    pad_ns = -pos % 4
    pos += pad_ns + len(ns_raw)
    pad_ids = -pos % 4
    pos += pad_ids + 12
    pad_pose = -pos % 8
    pos += pad_pose + _MARKER_BLOCK.size
    try:
        block = _MARKER_BLOCK.pack(*_floats(f.position, 3, "position"), *_floats(f.orientation, 4, "orientation"),
                                   *_floats(f.scale, 3, "scale"), *_floats(f.color, 4, "color"),
                                   *split_stamp(f.lifetime_ns), bool(f.frame_locked))
    except struct.error:
        raise ValueError(f"lifetime_ns={f.lifetime_ns!r} is not an integer nanosecond duration within the int32 "
                         f"seconds range") from None
    parts = [ENCAPSULATION, _pack_stamp(f.stamp_ns), frame, _ZEROS[:pad_ns], ns_raw, _ZEROS[:pad_ids],
             struct.pack("<iii", _check_int32(f.id, "id"), marker_type, int(f.action)), _ZEROS[:pad_pose], block]
    w = _Writer(parts, pos)
    w.sequence(len(pts), 8, pts)
    w.sequence(len(cols), 4, cols)
    # From here on nothing is 8-aligned and the offset is a multiple of 4: the common all-default rest of
    # the message is one constant.
    if (f.uv_coordinates is None and f.texture_data is None and f.mesh_data is None and not f.texture_resource
            and not f.texture_stamp_ns and not f.texture_frame_id and not f.texture_format and not f.text
            and not f.mesh_resource and not f.mesh_filename):
        parts.append(_MARKER_TAIL_EMBEDDED if f.mesh_use_embedded_materials else _MARKER_TAIL)
        return b"".join(parts)
    uvs = (_float_rows(f.uv_coordinates, 2, "uv_coordinates", np.float32) if f.uv_coordinates is not None
           else np.zeros((0, 2), dtype=np.float32))
    w.string(_encode_string(f.texture_resource, "texture_resource"))
    w.align(4)
    w.header(f.texture_stamp_ns, f.texture_frame_id)
    w.string(_encode_string(f.texture_format, "texture_format"))
    data = _optional_bytes(f.texture_data, "texture_data")
    w.sequence(len(data), 1, data)
    w.sequence(len(uvs), 4, uvs)
    w.string(_encode_string(f.text, "text"))
    w.string(_encode_string(f.mesh_resource, "mesh_resource"))
    w.string(_encode_string(f.mesh_filename, "mesh_filename"))
    data = _optional_bytes(f.mesh_data, "mesh_data")
    w.sequence(len(data), 1, data)
    w.raw(b"\x01" if f.mesh_use_embedded_materials else b"\x00")
    return w.getvalue()


class MarkerPointsSerializer:
    """Fast path for a marker whose only per-tick changes are its stamp and its ``points`` (a fixed number):
    the flocks' SPHERE_LIST / TRIANGLE_LIST.  The same bytes as :func:`marker` with those fields.

    The message is laid out once in a buffer; :attr:`points` is an ``(n, 3)`` float64 view of its points, for
    the caller to write into (the fish kernel writes its vertices there directly), and :meth:`serialize`
    patches the stamp and returns a *memoryview* of the buffer — no copy; valid until the next call (hand it
    to :func:`marker_array`, which copies it once into the array).  The buffer starts 4 bytes into an
    allocation, so the points, 8-aligned in the message body, are 8-aligned in memory too.  Not thread-safe.
    """

    _SENTINEL = np.float64(-1.2345678901234567e-300)  # marks the points while the layout is found

    def __init__(self, count: int, **fields) -> None:
        if "points" in fields or "stamp_ns" in fields:
            raise TypeError("MarkerPointsSerializer sets points and stamp_ns itself")
        template = marker(MarkerFields(points=np.full((count, 3), self._SENTINEL), **fields))
        block = np.full(3 * count, self._SENTINEL).tobytes()
        offset = template.find(block) if count else len(template)
        if count and (offset < 0 or (offset - 4) % 8):
            raise AssertionError("marker points not found 8-aligned in the template")  # pragma: no cover
        self.count = count
        self._storage = np.zeros(len(template) + 4, dtype=np.uint8)
        self._message = self._storage[4:]
        self._message[:] = np.frombuffer(template, dtype=np.uint8)
        #: (count, 3) float64 view of the points inside the message
        self.points = self._storage[4 + offset:4 + offset + 24 * count].view("<f8").reshape(count, 3)
        self._view = memoryview(self._message)

    def serialize(self, stamp_ns: int) -> memoryview:
        self._message[4:12] = np.frombuffer(_pack_stamp(stamp_ns), dtype=np.uint8)
        return self._view


class MarkerPoseSerializer:
    """Fast path for a marker whose only per-tick changes are its stamp and its pose (the bodies' markers): the
    same bytes as :func:`marker` with those fields, from a template laid out once (patching 9 numbers
    costs a few microseconds; building the marker, ~10 times that).  Not thread-safe."""

    _SENTINEL = -1.2345678901234567e-300  # marks the pose while the layout is found
    _POSE = struct.Struct("<7d")

    def __init__(self, **fields) -> None:
        if {"position", "orientation", "stamp_ns"} & set(fields):
            raise TypeError("MarkerPoseSerializer sets position, orientation and stamp_ns itself")
        sentinel = self._SENTINEL
        template = marker(MarkerFields(position=(sentinel,) * 3, orientation=(sentinel,) * 4, **fields))
        self._offset = template.find(self._POSE.pack(*(self._SENTINEL,) * 7))
        if self._offset < 0:
            raise AssertionError("marker pose not found in the template")  # pragma: no cover
        self._buffer = bytearray(template)

    def serialize(self, stamp_ns: int, position, orientation) -> bytes:
        """``position`` (3 numbers), ``orientation`` (4: x, y, z, w) — sequences of Python or numpy floats."""
        self._buffer[4:12] = _pack_stamp(stamp_ns)
        try:
            self._POSE.pack_into(self._buffer, self._offset, *position, *orientation)
        except struct.error:
            raise ValueError(f"a marker pose needs 3 + 4 numbers, got {position!r} and {orientation!r}") from None
        return bytes(self._buffer)


def _default_marker_tail(embedded: bool) -> bytes:
    """The bytes after ``colors`` when texture, uv_coordinates, text and mesh fields are all empty."""
    w = _Writer([], 0)  # any multiple of 4 as the start gives the same bytes
    w.string(_encode_string("", "texture_resource"))
    w.align(4)
    w.header(0, "")
    w.string(_encode_string("", "texture_format"))
    w.sequence(0, 1, b"")  # texture.data
    w.sequence(0, 4, b"")  # uv_coordinates
    for _ in range(3):  # text, mesh_resource, mesh_file.filename
        w.string(_encode_string("", "string"))
    w.sequence(0, 1, b"")  # mesh_file.data
    w.raw(b"\x01" if embedded else b"\x00")
    return b"".join(w.parts)


# pose (7 float64) + scale (3 float64) + color (4 float32) + lifetime (int32, uint32) + frame_locked (bool):
# contiguous without padding once the pose is 8-aligned.
_MARKER_BLOCK = struct.Struct("<10d4fiI?")
_NO_POINTS = np.zeros((0, 3))
_NO_COLORS = np.zeros((0, 4), dtype=np.float32)
_MARKER_TAIL = _default_marker_tail(False)
_MARKER_TAIL_EMBEDDED = _default_marker_tail(True)


def marker_deleteall(stamp_ns: int = 0, frame_id: str = "", ns: str = "") -> bytes:
    """A DELETEALL marker (removes all markers, or those of ``ns`` if given)."""
    return marker(MarkerFields(marker_type=ARROW, action=DELETEALL, stamp_ns=stamp_ns, frame_id=frame_id, ns=ns))


# ----------------------------------------------------------------------------------------- MarkerArray
# The layout of a Marker as a walk: ("fixed", align, size) | ("string",) | ("seq", element_align, element_size).
# Only the part up to the last 8-aligned item is walked when a marker is moved to a new offset (see below).
_MARKER_LAYOUT_TO_LAST_F64 = (
    ("fixed", 4, 8),    # header.stamp
    ("string",),        # header.frame_id
    ("string",),        # ns
    ("fixed", 4, 12),   # id, type, action
    ("fixed", 8, 80),   # pose (7 float64) + scale (3 float64)
    ("fixed", 4, 25),   # color (4 float32) + lifetime (int32, uint32) + frame_locked (bool)
    ("seq", 8, 24),     # points: geometry_msgs/Point[]
)


def _rephase(body: memoryview, dst_offset: int, layout, out: list) -> int:
    """Append to ``out`` the pieces of a CDR body serialized at offset 0, re-padded to start at ``dst_offset``.

    ``dst_offset`` must be a multiple of 4.  Items aligned on at most 4 keep their padding (source and
    destination offsets stay congruent mod 4), so only the padding before 8-aligned items can change:
    the walk follows ``layout`` (which must end with the last 8-aligned item) and copies the rest verbatim.
    Returns the destination offset after the body.
    """
    src, dst = 0, dst_offset
    for item in layout:
        kind = item[0]
        if kind == "fixed":
            _, align, size = item
            src += -src % align
            pad = -dst % align
            if pad:
                out.append(_ZEROS[:pad])
            out.append(body[src:src + size])
            src += size
            dst += pad + size
        elif kind == "string":
            pad = -src % 4  # == -dst % 4: the offsets are congruent mod 4
            if pad:
                out.append(_ZEROS[:pad])
            src += pad
            dst += pad
            length = _U32.unpack_from(body, src)[0]
            out.append(body[src:src + 4 + length])
            src += 4 + length
            dst += 4 + length
        else:  # sequence of fixed-size elements
            _, align, size = item
            pad_src, pad_dst = -src % 4, -dst % 4
            if pad_dst:
                out.append(_ZEROS[:pad_dst])
            src += pad_src
            dst += pad_dst
            count = _U32.unpack_from(body, src)[0]
            out.append(body[src:src + 4])
            src += 4
            dst += 4
            if count:
                src += -src % align
                pad = -dst % align
                if pad:
                    out.append(_ZEROS[:pad])
                out.append(body[src:src + count * size])
                src += count * size
                dst += pad + count * size
    out.append(body[src:])
    return dst + len(body) - src


def marker_array(markers: Sequence[bytes]) -> bytes:
    """``visualization_msgs/MarkerArray`` from markers serialized on their own (by :func:`marker`, or by
    ``rclpy.serialization.serialize_message``).

    A marker inside the array does not start at body offset 0 as it did on its own: the first one starts at 4
    (after the count), the next wherever the previous ended (rounded up to 4).  Its float64 fields (pose,
    scale, points) must be 8-aligned relative to the array's stream start, so each marker is re-padded for
    its new offset rather than copied verbatim.
    """
    out: list = [ENCAPSULATION, _U32.pack(len(markers))]
    pos = 4
    for index, data in enumerate(markers):
        view = memoryview(data)
        if view[:4] != ENCAPSULATION:
            raise ValueError(f"markers[{index}] does not start with the little-endian CDR encapsulation "
                             f"header 00 01 00 00 (got {bytes(view[:4]).hex(' ')})")
        pad = -pos % 4
        if pad:
            out.append(_ZEROS[:pad])
            pos += pad
        if pos % 8 == 0:  # same phase as on its own: copy verbatim
            out.append(view[4:])
            pos += len(view) - 4
        else:
            pos = _rephase(view[4:], pos, _MARKER_LAYOUT_TO_LAST_F64, out)
    return b"".join(out)


# ============================================================================================== Reading
# The other direction, for readers that have no rclpy (cgp_sim_ros.render reads bags with the mcap library
# alone): a MarkerArray's CDR bytes to numpy, the points and colours as views into the message (no copy).


class CdrError(ValueError):
    """Bytes that are not the CDR of the expected message."""


class _Reader:
    """Walks a little-endian CDR body; offsets are body offsets (after the encapsulation header)."""

    __slots__ = ("body", "pos")

    def __init__(self, data) -> None:
        view = memoryview(data)
        if len(view) < 4:
            raise CdrError(f"{len(view)} bytes: too short for a CDR encapsulation header")
        if bytes(view[:2]) != ENCAPSULATION[:2]:
            raise CdrError(f"encapsulation {bytes(view[:4]).hex(' ')} is not little-endian plain CDR (00 01 ..): "
                           "only CDR_LE is read")
        self.body = view[4:]
        self.pos = 0

    def take(self, size: int, align: int = 1) -> memoryview:
        self.pos += -self.pos % align
        end = self.pos + size
        if end > len(self.body):
            raise CdrError(f"truncated: {size} bytes wanted at body offset {self.pos}, {len(self.body)} in all")
        out = self.body[self.pos:end]
        self.pos = end
        return out

    def u32(self) -> int:
        return _U32.unpack(self.take(4, 4))[0]

    def string(self) -> str:
        length = self.u32()
        raw = self.take(length)
        if length == 0 or raw[-1] != 0:
            raise CdrError(f"string at body offset {self.pos - length} is not NUL-terminated")
        return bytes(raw[:-1]).decode("utf-8", errors="replace")

    def array(self, dtype: str, columns: int, element_align: int) -> np.ndarray:
        """A ``sequence<T>`` of fixed-size elements as an (n, columns) array (a view into the message)."""
        count = self.u32()
        item = np.dtype(dtype).itemsize * columns
        if count == 0:
            return np.zeros((0, columns), dtype=dtype)
        raw = self.take(count * item, element_align)
        return np.frombuffer(raw, dtype=dtype).reshape(count, columns)

    def skip_sequence(self, element_size: int, element_align: int) -> None:
        count = self.u32()
        if count:
            self.take(count * element_size, element_align)


@dataclass
class MarkerData:
    """A decoded ``visualization_msgs/Marker`` (the fields a renderer needs; the texture, uv coordinates and
    mesh bytes are skipped).  Arrays: ``position`` (3,), ``orientation`` (4,) x y z w, ``scale`` (3,),
    ``color`` (4,) RGBA, ``points`` (n, 3) float64, ``colors`` (n, 4) float32 (empty, or one per point)."""

    stamp_ns: int
    frame_id: str
    ns: str
    id: int
    type: int
    action: int
    position: np.ndarray
    orientation: np.ndarray
    scale: np.ndarray
    color: np.ndarray
    lifetime_ns: int
    frame_locked: bool
    points: np.ndarray
    colors: np.ndarray
    text: str = ""
    mesh_resource: str = ""


def _read_marker(r: _Reader) -> MarkerData:
    sec, nanosec = _STAMP.unpack(r.take(8, 4))
    frame_id = r.string()
    ns = r.string()
    marker_id, marker_type, action = struct.unpack("<iii", r.take(12, 4))
    values = _MARKER_BLOCK.unpack(r.take(_MARKER_BLOCK.size, 8))
    points = r.array("<f8", 3, 8)
    colors = r.array("<f4", 4, 4)
    r.string()  # texture_resource
    r.take(8, 4)  # texture.header.stamp
    r.string()  # texture.header.frame_id
    r.string()  # texture.format
    r.skip_sequence(1, 1)  # texture.data
    r.skip_sequence(8, 4)  # uv_coordinates (float32 u, v)
    text = r.string()
    mesh_resource = r.string()
    r.string()  # mesh_file.filename
    r.skip_sequence(1, 1)  # mesh_file.data
    r.take(1)  # mesh_use_embedded_materials
    return MarkerData(
        stamp_ns=sec * _NS_PER_S + nanosec, frame_id=frame_id, ns=ns, id=marker_id, type=marker_type,
        action=action, position=np.array(values[0:3]), orientation=np.array(values[3:7]),
        scale=np.array(values[7:10]), color=np.array(values[10:14]),
        lifetime_ns=values[14] * _NS_PER_S + values[15], frame_locked=bool(values[16]),
        points=points, colors=colors, text=text, mesh_resource=mesh_resource)


def read_marker(data) -> MarkerData:
    """Decode one serialized ``visualization_msgs/Marker``."""
    return _read_marker(_Reader(data))


def read_marker_array(data) -> list[MarkerData]:
    """Decode a serialized ``visualization_msgs/MarkerArray`` (as :func:`marker_array` writes it, or any other
    little-endian CDR writer: rclpy, rosbag2); raises :class:`CdrError` for bytes that are not one."""
    r = _Reader(data)
    count = r.u32()
    if count > len(r.body) // 100:  # a Marker is at least ~150 bytes: a count like this is garbage
        raise CdrError(f"MarkerArray claims {count} markers in {len(r.body)} bytes")
    return [_read_marker(r) for _ in range(count)]


@dataclass
class TransformData:
    """A decoded ``geometry_msgs/TransformStamped``: ``parent`` (header.frame_id) → ``child`` (child_frame_id),
    ``translation`` (3,) and ``rotation`` (4,) x y z w."""

    stamp_ns: int
    parent: str
    child: str
    translation: np.ndarray
    rotation: np.ndarray


def read_tf_message(data) -> list[TransformData]:
    """Decode a serialized ``tf2_msgs/TFMessage`` (``/tf``, ``/tf_static``, as :class:`TFMessageSerializer` or any
    little-endian CDR writer writes it); raises :class:`CdrError` for bytes that are not one."""
    r = _Reader(data)
    count = r.u32()
    if count > len(r.body) // 72:  # a TransformStamped is at least 8 + 4 + 4 + 56 bytes
        raise CdrError(f"TFMessage claims {count} transforms in {len(r.body)} bytes")
    out = []
    for _ in range(count):
        sec, nanosec = _STAMP.unpack(r.take(8, 4))
        parent = r.string()
        child = r.string()
        values = np.frombuffer(r.take(56, 8), dtype="<f8")
        out.append(TransformData(sec * _NS_PER_S + nanosec, parent, child, values[:3].copy(), values[3:].copy()))
    return out

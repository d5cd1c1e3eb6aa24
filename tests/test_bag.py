"""cgp_sim_ros.wire.bag.BagWriter: bags that rosbags and mcap_ros2 read, and what faults leave behind.

Every bag written here is read back by readers that share no code with the writer: rosbags' AnyReader over
the directory (which also re-parses each schema text and checks it against the recorded type hash),
mcap_ros2's decoder, and mcap's stream reader for the record-level checks.  Fault cases run the writer in a
child process and kill / signal it / limit its file size.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from cgp_sim_msgs.msg import ApplyWrench
from geometry_msgs.msg import PoseArray, WrenchStamped
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_ros2.reader import read_ros2_messages
from nav_msgs.msg import Odometry
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from cgp_sim_ros.wire import cdr, schemas
from cgp_sim_ros.wire.bag import BagExistsError, BagOptions, BagWriter, recover_bag

REPO = Path(__file__).resolve().parents[1]
DT = 16_666_667  # ns, 60 Hz


def read_rosbags(bag_dir: Path, default_typestore=None):
    """(topic, log_time, raw bytes, deserialized message) for every message, via rosbags over the directory."""
    out = []
    with AnyReader([bag_dir], default_typestore=default_typestore) as reader:
        for connection, timestamp, raw in reader.messages():
            out.append((connection.topic, timestamp, bytes(raw), reader.deserialize(raw, connection.msgtype)))
        counts = {c.topic: c.msgcount for c in reader.connections}
    return out, counts


def mcap_records(path: Path) -> list:
    """Every record of one file, read sequentially (the mcap library's stream reader)."""
    with open(path, "rb") as f:
        return list(StreamReader(f, validate_crcs=True).records)


def recovered_messages(path: Path) -> list:
    """Records readable from the start of a possibly damaged file: mcap's stream reader until it fails."""
    from mcap.records import Message

    found = []
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, validate_crcs=True).records:
                if isinstance(record, Message):
                    found.append(record)
        except Exception:  # noqa: BLE001 - the damaged tail
            pass
    return found


def last_chunk(data: bytes) -> tuple[int, int]:
    """(offset, record length) of the last Chunk record (opcode 0x06) of an MCAP file's bytes."""
    offset, found = 8, None
    while offset + 9 <= len(data):
        opcode, length = data[offset], int.from_bytes(data[offset + 1:offset + 9], "little")
        if opcode == 0x06:
            found = (offset, 9 + length)
        offset += 9 + length
    assert found is not None
    return found


def metadata(bag_dir: Path) -> dict:
    return yaml.safe_load((bag_dir / "metadata.yaml").read_text())["rosbag2_bagfile_information"]


# ------------------------------------------------------------------------------------------ round trip
@pytest.fixture
def recorded(tmp_path):
    """A short run of the node's kinds of messages, with what was written."""
    bag_dir = tmp_path / "run"
    bag = BagWriter(bag_dir, BagOptions(chunk_size=64 * 1024), custom_data={"scene": "test"})
    qos = QoSProfile(depth=10)
    bag.add_topic("/clock", "rosgraph_msgs/msg/Clock", qos)
    bag.add_topic("/cgp_sim/flocks/a/poses", "geometry_msgs/msg/PoseArray", qos)
    bag.add_topic("/cgp_sim/markers", "visualization_msgs/msg/MarkerArray", qos)
    bag.add_topic("/cgp_sim/bodies/ball/odom", "nav_msgs/msg/Odometry",
                  QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT))
    bag.add_topic("/cgp_sim/apply_wrench", "cgp_sim_msgs/ApplyWrench", qos)  # pkg/Type accepted
    odom = cdr.OdometryBatchSerializer("world", ["ball"])
    rng = np.random.default_rng(0)
    written = []
    for k in range(120):
        t = 1_000_000_000 + k * DT
        pos, quat = rng.normal(size=(50, 3)), rng.normal(size=(50, 4))
        msgs = [("/clock", cdr.clock(t)),
                ("/cgp_sim/flocks/a/poses", cdr.pose_array(t, "world", pos, quat)),
                ("/cgp_sim/markers", cdr.marker_array([
                    cdr.marker(cdr.MarkerFields(marker_type=cdr.SPHERE_LIST, frame_id="world", ns="a", points=pos)),
                    cdr.marker(cdr.MarkerFields(marker_type=cdr.SPHERE, frame_id="world", ns="ball",
                                                position=pos[0]))])),
                ("/cgp_sim/bodies/ball/odom", odom.serialize(t, pos[:1], quat[:1], pos[:1], pos[:1])[0])]
        if k % 40 == 0:  # a received command, serialized by rclpy
            cmd = ApplyWrench(body="ball")
            cmd.wrench.force.z = float(k)
            msgs.append(("/cgp_sim/apply_wrench", serialize_message(cmd)))
        for topic, data in msgs:
            assert bag.write(topic, data, t, t - 1000)
            written.append((topic, t, data))
    bag.close()
    assert bag.error is None and bag.dropped_messages == 0
    return bag_dir, written


def test_rosbags_reads_every_message_as_written(recorded):
    bag_dir, written = recorded
    got, counts = read_rosbags(bag_dir)
    assert sorted((t, ts, raw) for t, ts, raw, _ in got) == sorted(written)
    expected_counts = {}
    for topic, _, _ in written:
        expected_counts[topic] = expected_counts.get(topic, 0) + 1
    assert counts == expected_counts
    # Contents, through rosbags' own deserializer.
    poses = [(ts, msg) for topic, ts, _, msg in got if topic == "/cgp_sim/flocks/a/poses"]
    ours = [(ts, deserialize_message(raw, PoseArray)) for topic, ts, raw in written
            if topic == "/cgp_sim/flocks/a/poses"]
    for (ts, msg), (ts2, ref) in zip(poses, ours):
        assert ts == ts2 and msg.header.frame_id == "world"
        assert np.array_equal([[p.position.x, p.position.y, p.position.z] for p in msg.poses],
                              [[p.position.x, p.position.y, p.position.z] for p in ref.poses])
    forces = [msg.wrench.force.z for topic, _, _, msg in got if topic == "/cgp_sim/apply_wrench"]
    assert forces == [0.0, 40.0, 80.0]


def test_mcap_ros2_decodes_every_message(recorded):
    bag_dir, written = recorded
    decoded = list(read_ros2_messages(str(bag_dir / "run_0.mcap")))
    assert len(decoded) == len(written)
    by_topic = {}
    for m in decoded:
        by_topic.setdefault(m.channel.topic, []).append(m)
    clocks = by_topic["/clock"]
    assert [m.ros_msg.clock.sec * 10**9 + m.ros_msg.clock.nanosec for m in clocks] == \
        [t for topic, t, _ in written if topic == "/clock"]
    assert all(m.log_time_ns - m.publish_time_ns == 1000 for m in decoded)
    markers = by_topic["/cgp_sim/markers"][0].ros_msg.markers
    assert [m.type for m in markers] == [cdr.SPHERE_LIST, cdr.SPHERE] and len(markers[0].points) == 50


def test_file_layout_is_rosbag2s(recorded):
    from mcap.records import Channel, Header, Metadata, Schema

    bag_dir, written = recorded
    records = mcap_records(bag_dir / "run_0.mcap")
    header = next(r for r in records if isinstance(r, Header))
    assert header.profile == "ros2"
    found = {r.name: r for r in records if isinstance(r, Schema)}
    assert set(found) == {"rosgraph_msgs/msg/Clock", "geometry_msgs/msg/PoseArray",
                          "visualization_msgs/msg/MarkerArray", "nav_msgs/msg/Odometry",
                          "cgp_sim_msgs/msg/ApplyWrench"}
    for name, schema in found.items():
        assert schema.encoding == "ros2msg"
        assert schema.data.decode() == schemas.message_definition(name)
        store = get_typestore(Stores.EMPTY)  # an independent parse of the text gives the recorded hash
        store.register(get_types_from_msg(schema.data.decode(), name))
        assert store.hash_rihs01(name) == schemas.type_hash(name)
    channels = {r.topic: r for r in records if isinstance(r, Channel)}
    assert channels["/cgp_sim/bodies/ball/odom"].message_encoding == "cdr"
    odom_meta = channels["/cgp_sim/bodies/ball/odom"].metadata
    assert odom_meta["topic_type_hash"] == schemas.type_hash("nav_msgs/msg/Odometry")
    assert yaml.safe_load(odom_meta["offered_qos_profiles"])[0]["reliability"] == "best_effort"
    rosbag2_records = [r for r in records if isinstance(r, Metadata) and r.name == "rosbag2"]
    assert len(rosbag2_records) == 1
    embedded = yaml.safe_load(rosbag2_records[0].metadata["serialized_metadata"])
    assert embedded["message_count"] == len(written) and embedded["version"] == 9
    with open(bag_dir / "run_0.mcap", "rb") as f:  # finished: indexed summary with statistics
        summary = make_reader(f).get_summary()
    assert summary.statistics.message_count == len(written) and summary.chunk_indexes


def test_metadata_yaml_is_rosbag2s(recorded):
    bag_dir, written = recorded
    info = metadata(bag_dir)
    times = [t for _, t, _ in written]
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    assert info["relative_file_paths"] == ["run_0.mcap"]
    assert info["message_count"] == len(written)
    assert info["starting_time"]["nanoseconds_since_epoch"] == min(times)
    assert info["duration"]["nanoseconds"] == max(times) - min(times)
    assert info["files"] == [{"path": "run_0.mcap", "starting_time": {"nanoseconds_since_epoch": min(times)},
                              "duration": {"nanoseconds": max(times) - min(times)},
                              "message_count": len(written)}]
    assert (info["compression_format"], info["compression_mode"]) == ("", "")
    assert info["custom_data"] == {"scene": "test"} and info["ros_distro"] == "jazzy"
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    odom = topics["/cgp_sim/bodies/ball/odom"]
    assert odom["message_count"] == 120
    assert odom["topic_metadata"]["type"] == "nav_msgs/msg/Odometry"
    assert odom["topic_metadata"]["serialization_format"] == "cdr"
    assert odom["topic_metadata"]["type_description_hash"] == schemas.type_hash("nav_msgs/msg/Odometry")
    assert odom["topic_metadata"]["offered_qos_profiles"][0]["reliability"] == "best_effort"
    assert topics["/cgp_sim/apply_wrench"]["topic_metadata"]["type"] == "cgp_sim_msgs/msg/ApplyWrench"


def test_metadata_exists_from_the_start_and_lists_topics(tmp_path):
    bag = BagWriter(tmp_path / "early")
    bag.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    assert bag.flush(timeout=5)
    # An empty but valid bag already.  (MCAP writes a topic's schema with its first chunk of messages, so
    # this bag has no definitions yet: rosbags needs its own type store for it.)
    got, counts = read_rosbags(tmp_path / "early", default_typestore=get_typestore(Stores.ROS2_JAZZY))
    assert got == [] and counts == {"/clock": 0}
    bag.write("/clock", cdr.clock(5), 5)
    bag.close()
    assert [g[:2] for g in read_rosbags(tmp_path / "early")[0]] == [("/clock", 5)]


def _nice(thread_id: int) -> int:
    """A thread's nice value, as the kernel reports it (/proc/<pid>/task/<tid>/stat, field 19)."""
    stat = Path(f"/proc/self/task/{thread_id}/stat").read_text()
    return int(stat.rsplit(")", 1)[1].split()[16])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice values are Linux's")
def test_the_writer_thread_runs_at_a_lower_priority_than_the_caller_and_loses_nothing(tmp_path):
    """The writer thread yields the cores to the simulation (nice + writer_nice, its own thread only: the
    caller keeps its priority) and still writes every message."""
    import threading

    caller = _nice(threading.get_native_id())
    bag = BagWriter(tmp_path / "low")
    other = BagWriter(tmp_path / "same", BagOptions(writer_nice=0))
    for writer in (bag, other):
        writer.add_topic("/clock", "rosgraph_msgs/msg/Clock")
        for k in range(50):
            writer.write("/clock", cdr.clock(k), k)
        assert writer.flush(timeout=5)
    assert _nice(bag._thread.native_id) == min(caller + 10, 19)
    assert _nice(other._thread.native_id) == caller
    assert _nice(threading.get_native_id()) == caller
    bag.close()
    other.close()
    assert [g[1] for g in read_rosbags(tmp_path / "low")[0]] == list(range(50))


def _wait_until(condition, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


def test_a_held_writer_takes_nothing_until_woken_within_its_bounds(tmp_path, monkeypatch):
    """hold(): the writer thread leaves the queue alone while a real-time tick runs — it polls every 5 ms, so
    0.2 s held with nothing taken shows the hold — and takes it all after wake().  Bounded: with hold_bytes
    waiting it works anyway, a flush is never held, and neither is a hold its caller never ended."""
    from cgp_sim_ros.wire import bag as bag_module

    # a hold that cannot age out while this test runs, however slowly (the age bound is checked at the end)
    monkeypatch.setattr(bag_module, "_HOLD_MAX_S", 60.0)
    payload = cdr.pose_array(0, "w", np.zeros((17, 3)), np.zeros((17, 4)))  # 980 B
    bag = BagWriter(tmp_path / "held", BagOptions(hold_bytes=5_000))
    bag.add_topic("/x", "geometry_msgs/msg/PoseArray")
    assert bag.flush(timeout=5)

    bag.hold()
    for k in range(4):  # 3.9 kB: under hold_bytes
        bag.write("/x", payload, k)
    time.sleep(0.2)
    assert bag._drained_bytes == 0  # nothing taken while held
    bag.wake()
    assert _wait_until(lambda: bag._drained_bytes == 4 * len(payload))

    bag.hold()  # past hold_bytes: the writer works beside the caller
    for k in range(4, 14):  # 9.8 kB
        bag.write("/x", payload, k)
    assert _wait_until(lambda: bag._enqueued_bytes - bag._drained_bytes < 5_000)
    assert bag._held_since is not None  # still held
    bag.write("/x", payload, 14)
    assert bag.flush(timeout=5)  # a flush is not held: everything so far is written
    assert bag._drained_bytes == 15 * len(payload)

    monkeypatch.setattr(bag_module, "_HOLD_MAX_S", 0.05)
    bag.hold()  # never woken: after 0.05 s the hold no longer applies
    bag.write("/x", payload, 15)
    assert _wait_until(lambda: bag._drained_bytes == 16 * len(payload))
    bag.close()
    assert [ts for _, ts, _, _ in read_rosbags(tmp_path / "held")[0]] == list(range(16))


def _metadata_count(bag_dir: Path) -> int:
    info = yaml.safe_load((bag_dir / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return info["message_count"]


def test_the_periodic_fsync_runs_beside_the_writer_and_metadata_never_counts_ahead(tmp_path, monkeypatch):
    """The fsync every sync_interval_s runs on the bag's sync thread: while it is held up (here until the test
    lets it go) the writer thread goes on committing what comes in.  A metadata.yaml stored by a sync describes
    the state it was asked to fsync: it never counts more messages than were committed when a sync began; at
    close, every message."""
    import threading

    real_fsync = os.fsync
    synced: list[tuple[str, int]] = []  # (thread, messages committed to the file when its fsync began)
    sync_started, release = threading.Event(), threading.Event()
    bag = BagWriter(tmp_path / "bg", BagOptions(chunk_size=512, sync_interval_s=0.0))  # a sync due at every commit

    def fsync(fd):
        name = threading.current_thread().name
        if name.startswith("bag-sync"):
            synced.append((name, bag._committed_messages))
            sync_started.set()
            release.wait(30)
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    bag.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    k = 0
    while not sync_started.is_set():  # commits until the first background sync has begun
        assert k < 10_000
        bag.write("/clock", cdr.clock(k), k)
        k += 1
        time.sleep(0.001)
    committed_at_start = bag._committed_messages
    for _ in range(60):  # 60 more messages (> 512 B of chunks) while that fsync is held up
        bag.write("/clock", cdr.clock(k), k)
        k += 1
    assert _wait_until(lambda: bag._committed_messages >= committed_at_start + 50)
    assert not bag._sync_idle.is_set()  # ... all committed while the first sync was still in its fsync
    release.set()
    assert _wait_until(bag._sync_idle.is_set)
    assert _metadata_count(tmp_path / "bg") <= max(count for _, count in synced)
    bag.close()
    assert {name for name, _ in synced} == {"bag-sync:bg"}
    assert _metadata_count(tmp_path / "bg") == k
    assert [ts for _, ts, _, _ in read_rosbags(tmp_path / "bg")[0]] == list(range(k))


def test_a_failing_background_fsync_is_reported_and_the_bag_keeps_what_was_committed(tmp_path, monkeypatch):
    real_fsync = os.fsync
    errors = []

    def fsync(fd):
        import threading

        if threading.current_thread().name.startswith("bag-sync"):
            raise OSError(5, "Input/output error")
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    bag = BagWriter(tmp_path / "eio", BagOptions(chunk_size=256, sync_interval_s=0.0), on_error=errors.append)
    bag.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    for k in range(200):
        if not bag.write("/clock", cdr.clock(k), k):
            break
        time.sleep(0.001)
    assert _wait_until(lambda: bag.error is not None)
    bag.close()
    assert len(errors) == 1 and "syncing" in errors[0] and "Input/output error" in errors[0]
    got = [ts for _, ts, _, _ in read_rosbags(tmp_path / "eio")[0]]
    assert got == list(range(len(got)))  # what was committed, in order, readable


def test_topic_added_mid_recording_is_in_metadata_yaml_from_the_next_commit(tmp_path):
    """A topic added while recording (a spawned body) is listed by metadata.yaml, with its committed message
    count, while the recording goes on — without a flush or close (the writer no longer rewrites the file per
    new topic, but at the next chunk commit)."""
    bag_dir = tmp_path / "mid"
    bag = BagWriter(bag_dir, BagOptions(chunk_interval_s=0.05))
    bag.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    for k in range(3):
        bag.write("/clock", cdr.clock(k), k)
    bag.add_topic("/cgp_sim/bodies/box/odom", "nav_msgs/msg/Odometry")

    def listed() -> dict:
        meta = yaml.safe_load((bag_dir / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        return {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}

    deadline = time.monotonic() + 10.0
    k = 3
    while listed().get("/cgp_sim/bodies/box/odom", 0) < 1 and time.monotonic() < deadline:
        bag.write("/clock", cdr.clock(k), k)
        bag.write("/cgp_sim/bodies/box/odom", serialize_message(Odometry()), k)
        k += 1
        time.sleep(0.02)
    counts = listed()
    bag.close()
    assert counts.get("/cgp_sim/bodies/box/odom", 0) >= 1, counts
    assert counts["/clock"] >= 4


# ---------------------------------------------------------------------------------------------- split
def write_sequence(bag: BagWriter, n: int, period_ns: int = DT, size: int = 20):
    bag.add_topic("/cgp_sim/flocks/a/poses", "geometry_msgs/msg/PoseArray")
    bag.add_topic("/cgp_sim/wrench", "geometry_msgs/msg/WrenchStamped")
    written = []
    for k in range(n):
        t = k * period_ns
        data = cdr.pose_array(t, "world", np.full((size, 3), float(k)), np.tile([0, 0, 0, 1.0], (size, 1)))
        bag.write("/cgp_sim/flocks/a/poses", data, t)
        written.append(("/cgp_sim/flocks/a/poses", t, data))
        if k % 7 == 0:
            w = WrenchStamped()
            w.wrench.force.x = float(k)
            data = serialize_message(w)
            bag.write("/cgp_sim/wrench", data, t)
            written.append(("/cgp_sim/wrench", t, data))
    return written


def test_split_by_size_reads_back_as_one_bag(tmp_path):
    bag = BagWriter(tmp_path / "big", BagOptions(chunk_size=8 * 1024, max_bytes=40 * 1024, compression="none"))
    written = write_sequence(bag, 300)
    bag.close()
    info = metadata(tmp_path / "big")
    names = [f"big_{i}.mcap" for i in range(len(info["relative_file_paths"]))]
    assert len(names) >= 4 and info["relative_file_paths"] == names
    assert sorted(p.name for p in (tmp_path / "big").glob("*.mcap")) == sorted(names)
    assert [f["path"] for f in info["files"]] == names
    assert sum(f["message_count"] for f in info["files"]) == info["message_count"] == len(written)
    for name in names[:-1]:  # a file is closed once it reaches max_bytes: at most one chunk more
        assert 40 * 1024 <= (tmp_path / "big" / name).stat().st_size <= 40 * 1024 + 16 * 1024
    got, _ = read_rosbags(tmp_path / "big")
    assert [(t, ts, raw) for t, ts, raw, _ in got] == written
    for name in names:  # every file is a finished MCAP with all topics
        with open(tmp_path / "big" / name, "rb") as f:
            summary = make_reader(f).get_summary()
        assert {c.topic for c in summary.channels.values()} == {"/cgp_sim/flocks/a/poses", "/cgp_sim/wrench"}


def test_split_by_duration(tmp_path):
    bag = BagWriter(tmp_path / "long", BagOptions(max_duration_s=1.0))
    written = write_sequence(bag, 50, period_ns=100_000_000)  # 5 s of log time at 10 Hz
    bag.close()
    info = metadata(tmp_path / "long")
    assert len(info["files"]) == 5
    for f in info["files"]:
        assert f["duration"]["nanoseconds"] <= 1_000_000_000
    got, _ = read_rosbags(tmp_path / "long")
    assert [(t, ts, raw) for t, ts, raw, _ in got] == written


# ---------------------------------------------------------------------------------------------- faults
CHILD = textwrap.dedent("""
    import os, resource, signal, sys, time
    import numpy as np
    from cgp_sim_ros.wire import cdr
    from cgp_sim_ros.wire.bag import BagOptions, BagWriter

    mode, bag_dir = sys.argv[1], sys.argv[2]
    if mode == "fsize":  # a disk that fills up: files may not grow past 150 kB
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (150_000, resource.RLIM_INFINITY))
    errors = []
    bag = BagWriter(bag_dir, BagOptions(chunk_size=16 * 1024, chunk_interval_s=0.05, compression="lz4",
                                        max_bytes=20_000 if mode == "kill" else 0), on_error=errors.append)
    bag.add_topic("/poses", "geometry_msgs/msg/PoseArray")
    accepted = 0
    if mode == "signal":
        def finish(signum, frame):
            bag.close()
            print("closed", accepted, bag.written_messages, flush=True)
            sys.exit(0)
        signal.signal(signal.SIGTERM, finish)
        signal.signal(signal.SIGINT, finish)
    print("ready", flush=True)
    k = 0
    while True:
        t = k * 16_666_667
        data = cdr.pose_array(t, "world", np.full((30, 3), float(k)), np.tile([0, 0, 0, 1.0], (30, 1)))
        accepted += bag.write("/poses", data, t)  # never raises, even when the disk is full
        k += 1
        if k % 10 == 0:
            time.sleep(0.005)
            print("committed", bag.committed_messages, flush=True)
        if mode == "fsize" and errors and k > 3000:
            bag.close()
            print("error", repr(errors), len(errors), flush=True)
            print("end", k, accepted, bag.committed_messages, bag.dropped_messages, flush=True)
            sys.exit(0)
""")


def start_child(tmp_path, mode):
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen([sys.executable, str(script), mode, str(tmp_path / "bag")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, cwd=REPO)
    assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
    return proc


def wait_committed(proc, at_least: int, timeout: float = 30.0) -> int:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stdout.readline().split()
        if line and line[0] == "committed" and int(line[1]) >= at_least:
            return int(line[1])
    raise AssertionError("the child did not commit in time")


def assert_prefix_of_sequence(messages_data: list[bytes], at_least: int):
    """The recovered messages are messages 0, 1, 2, ... of the child's sequence, in order, no gaps."""
    assert len(messages_data) >= at_least
    for k, data in enumerate(messages_data):
        msg = deserialize_message(data, PoseArray)
        assert msg.poses[0].position.x == float(k) and msg.header.stamp.nanosec == (k * 16_666_667) % 10**9


def test_sigkill_leaves_every_committed_chunk_readable(tmp_path):
    proc = start_child(tmp_path, "kill")  # (this child also splits files at 20 kB)
    committed = wait_committed(proc, 600)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    bag_dir = tmp_path / "bag"
    files = [bag_dir / name for name in metadata(bag_dir)["relative_file_paths"]]
    assert len(files) >= 2 and all(f.exists() for f in files)
    on_disk = sorted(bag_dir.glob("bag_*.mcap"), key=lambda f: int(f.stem.split("_")[1]))
    unlisted = on_disk[len(files):]
    assert on_disk[:len(files)] == files and len(unlisted) <= 1
    with open(files[-1], "rb") as f:
        finished = make_reader(f).get_summary() is not None
    if finished:
        # The kill landed inside a split: the last listed file was finished and its successor not yet listed in
        # metadata.yaml (not yet created, or created with its header only: it holds no message).
        assert all(recovered_messages(f) == [] for f in unlisted)
    else:  # the usual kill case: the last file is cut mid-write, without a summary, and it is the last one
        assert not unlisted
    recovered = [m for f in files for m in recovered_messages(f)]
    assert_prefix_of_sequence([m.data for m in recovered], committed)
    got, _ = read_rosbags(bag_dir)
    assert [raw for _, _, raw, _ in got] == [m.data for m in recovered]
    assert sum(len(list(read_ros2_messages(str(f)))) for f in files) == len(recovered)

    # Power loss in the middle of a commit: a torn last chunk.  mcap's stream reader still returns every
    # chunk before it, and recover_bag makes the directory readable by rosbags again.
    data = files[-1].read_bytes()
    start, length = last_chunk(data)
    files[-1].write_bytes(data[: start + length // 2])  # half of the last chunk on disk, nothing after it
    torn = [m for f in files for m in recovered_messages(f)]
    assert_prefix_of_sequence([m.data for m in torn], 1)
    assert len(torn) < len(recovered)
    kept = recover_bag(bag_dir)
    assert sum(kept.values()) == len(torn)
    got, counts = read_rosbags(bag_dir)
    assert [raw for _, _, raw, _ in got] == [m.data for m in torn] and counts == {"/poses": len(torn)}
    assert metadata(bag_dir)["message_count"] == len(torn)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_signal_finishes_the_file(tmp_path, signum):
    proc = start_child(tmp_path, "signal")
    wait_committed(proc, 100)
    proc.send_signal(signum)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    closed = [line.split() for line in out.splitlines() if line.startswith("closed")][0]
    accepted, written = int(closed[1]), int(closed[2])
    assert written == accepted or written == accepted + 1  # the signal may land inside a write()
    mcap_file = tmp_path / "bag" / "bag_0.mcap"
    with open(mcap_file, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count == written
    assert metadata(tmp_path / "bag")["message_count"] == written
    got, _ = read_rosbags(tmp_path / "bag")
    assert_prefix_of_sequence([raw for _, _, raw, _ in got], written)
    assert len(got) == written


def test_disk_full_is_reported_once_and_never_raised(tmp_path):
    proc = start_child(tmp_path, "fsize")
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    error_line = next(line for line in out.splitlines() if line.startswith("error"))
    assert "File too large" in error_line and "bag_0.mcap" in error_line and error_line.endswith(" 1")
    end = [line.split() for line in out.splitlines() if line.startswith("end")][0]
    calls, accepted, committed, dropped = map(int, end[1:])
    assert 0 < committed <= accepted < calls
    assert calls == committed + dropped  # every message is either in the bag or counted as dropped
    # The file is back at its last committed state: readable by rosbags, a prefix of the sequence.
    got, _ = read_rosbags(tmp_path / "bag")
    assert len(got) == committed
    assert_prefix_of_sequence([raw for _, _, raw, _ in got], committed)


def test_unwritable_directory_gives_a_clear_error_and_no_exception(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    errors = []
    bag = BagWriter(blocker / "bag", on_error=errors.append)
    assert len(errors) == 1 and bag.error == errors[0]
    assert "cannot record the bag" in errors[0] and str(blocker / "bag") in errors[0]
    bag.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    assert bag.write("/clock", cdr.clock(1), 1) is False
    assert bag.dropped_messages == 1
    bag.close()
    assert len(errors) == 1


def test_existing_non_empty_directory_is_refused(tmp_path):
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "metadata.yaml").write_text("precious")
    with pytest.raises(BagExistsError, match="already exists and is not empty"):
        BagWriter(tmp_path / "old")
    assert (tmp_path / "old" / "metadata.yaml").read_text() == "precious"
    (tmp_path / "empty").mkdir()
    BagWriter(tmp_path / "empty").close()  # an empty directory is fine
    assert (tmp_path / "empty" / "empty_0.mcap").exists()


# --------------------------------------------------------------------------------------- queue bound
def test_queue_full_drop_policy_drops_and_reports(tmp_path):
    errors = []
    bag = BagWriter(tmp_path / "drop", BagOptions(max_queue_bytes=10_000, on_queue_full="drop"),
                    on_error=errors.append)
    bag.add_topic("/x", "geometry_msgs/msg/PoseArray")
    assert bag.flush(timeout=5)
    bag._gate.clear()  # a disk that does not keep up: the writer thread makes no progress
    payloads = [cdr.pose_array(k, "w", np.full((17, 3), k), np.zeros((17, 4))) for k in range(30)]  # 980 B
    accepted = [bag.write("/x", p, k) for k, p in enumerate(payloads)]
    fits = 10_000 // len(payloads[0])  # messages that fit under the bound
    assert accepted == [True] * fits + [False] * (30 - fits)
    assert bag.dropped_messages == accepted.count(False) and len(errors) == 1 and "queue full" in errors[0]
    bag._gate.set()
    bag.close()
    got, _ = read_rosbags(tmp_path / "drop")
    assert [raw for _, _, raw, _ in got] == [p for p, ok in zip(payloads, accepted) if ok]


def test_queue_full_block_policy_loses_nothing(tmp_path):
    bag = BagWriter(tmp_path / "block", BagOptions(max_queue_bytes=20_000, chunk_size=4096))
    written = write_sequence(bag, 400, size=40)  # 2.3 kB messages: the caller is much faster than the disk
    bag.close()
    assert bag.dropped_messages == 0 and bag.error is None
    assert bag.max_queued_bytes <= 20_000 + 2_300
    got, _ = read_rosbags(tmp_path / "block")
    assert [(t, ts, raw) for t, ts, raw, _ in got] == written


def test_stalled_writer_stops_blocking_the_caller(tmp_path):
    errors = []
    bag = BagWriter(tmp_path / "stall", BagOptions(max_queue_bytes=2_000, block_timeout_s=0.2),
                    on_error=errors.append)
    bag.add_topic("/x", "geometry_msgs/msg/PoseArray")
    bag._gate.clear()
    data = cdr.pose_array(1, "w", np.zeros((27, 3)), np.zeros((27, 4)))  # 1540 B
    assert bag.write("/x", data, 1) is True
    t0 = time.monotonic()
    assert bag.write("/x", data, 2) is False  # returned: the caller is not blocked for ever ...
    assert time.monotonic() - t0 > 0.15  # ... after waiting out the 0.2 s block timeout
    assert bag.write("/x", data, 3) is False  # from now on: dropped at once
    assert len(errors) == 1 and "stalled" in errors[0]
    bag._gate.set()
    bag.close()
    assert [ts for _, ts, _, _ in read_rosbags(tmp_path / "stall")[0]] == [1]


# ------------------------------------------------------------------------------------------ bad usage
def test_bad_usage_is_a_clear_error(tmp_path):
    with BagWriter(tmp_path / "usage") as bag:
        with pytest.raises(KeyError, match="add_topic"):
            bag.write("/nope", b"\x00\x01\x00\x00", 0)
        bag.add_topic("/c", "rosgraph_msgs/msg/Clock")
        with pytest.raises(TypeError, match="bytes"):
            bag.write("/c", bytearray(cdr.clock(0)), 0)
        with pytest.raises(FileNotFoundError, match="NoSuch"):
            bag.add_topic("/d", "std_msgs/msg/NoSuch")
        with pytest.raises(ValueError, match="was added as"):
            bag.add_topic("/c", "std_msgs/msg/Header")
        with pytest.raises(ValueError, match="not a valid ROS topic name"):
            bag.add_topic("bad name", "std_msgs/msg/Header")
    assert bag.write("/c", cdr.clock(0), 0) is False  # after close: ignored
    with pytest.raises(ValueError, match="compression"):
        BagWriter(tmp_path / "x", BagOptions(compression="gzip"))

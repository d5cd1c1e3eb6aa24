"""Issue 8, faults: a subscriber that never reads, shutdown from any state, and bag directories that cannot be
created or that point elsewhere.  The node runs as its own process (the `cgp-sim` script); everything is
observed from this process over DDS, or from the files the node leaves, and waited for with deadlines.
(Bad inputs are in tests/test_robustness_commands.py and tests/test_robustness_scenes.py; the long run is
tests/test_soak.py.)
"""

from __future__ import annotations

import json
import signal
import textwrap
import time

import psutil
import pytest
import yaml
from geometry_msgs.msg import PoseArray
from mcap.reader import make_reader
from ros_probe import PeerProcess, pause, step
from rosgraph_msgs.msg import Clock
from std_srvs.srv import Trigger
from test_node_bag import read_bag
from test_robustness_commands import assert_clock_advances_by_dt, stamp_ns

RATE_HZ = 60.0
DT_NS = round(1e9 / RATE_HZ)

# zero_g's two bodies and a 3,000-boid flock: 168 kB of flock poses and 73 kB of markers per tick (~14 MB/s at
# 60 Hz), at a tick cost that leaves this 2-core machine room to keep 60 Hz.
BIG_FLOCK_SCENE = {
    "description": "zero_g's bodies and a 3,000-boid flock: big messages at a small tick cost",
    "world": {"gravity": [0, 0, 0], "ground": False, "integrator": "implicit_midpoint", "substeps": 4},
    "bodies": [
        {"name": "box", "shape": "box", "size": [0.2, 0.4, 0.6], "mass": 2.0, "position": [0, 0, 2]},
        {"name": "spinner", "shape": "box", "size": [0.4, 0.4, 0.2], "mass": 1.0, "position": [3, 0, 2],
         "angular_velocity": [0, 0, 3.141592653589793]},
    ],
    "flocks": [
        {"name": "school", "count": 3000, "spawn": {"center": [0, 30, 12], "extent": [30, 30, 12]},
         "radius": 2.0, "separation_radius": 1.0, "min_speed": 0.5, "max_speed": 2.0,
         "bounds": {"min": [-25, 5, 1], "max": [25, 55, 25]}, "model": "sphere", "seed": 11},
    ],
}


def write_scene(path, scene: dict) -> str:
    path.write_text(yaml.safe_dump(scene, sort_keys=False))
    return str(path)


def tick(msg) -> int:
    """The tick a /clock or stamped message is of (rclpy and rosbags messages alike)."""
    t = msg.clock if hasattr(msg, "clock") else msg.header.stamp
    return (t.sec * 1_000_000_000 + t.nanosec) // DT_NS


def wait_ticking(probe, node, clock, count: int, timeout: float = 30.0) -> None:
    """Wait for ``count`` /clock messages, failing at once (with the node's log) if the node dies."""
    def ready() -> bool:
        assert node.alive(), f"the node exited with {node.proc.returncode}:\n{node.log()[-4000:]}"
        return len(clock.messages) >= count

    try:
        probe.spin_until(ready, timeout, f"{count} /clock messages")
    except AssertionError as exc:
        raise AssertionError(f"{exc}; node log:\n{node.log()[-4000:]}") from None


def clock_rate(clock, since: float, until: float) -> float:
    """Ticks per wall second from the /clock stamps received in [since, until] (monotonic)."""
    picked = [(t, stamp_ns(m)) for t, m in zip(clock.times, clock.messages) if since <= t <= until]
    assert len(picked) >= 2, f"{len(picked)} /clock messages in the window"
    (t0, s0), (t1, s1) = picked[0], picked[-1]
    return (s1 - s0) / DT_NS / (t1 - t0)


# ---- slow consumer ----------------------------------------------------------------------------------------

STALLED_READER = textwrap.dedent("""
    import sys, threading
    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from geometry_msgs.msg import PoseArray
    from visualization_msgs.msg import MarkerArray

    rclpy.init()
    node = rclpy.create_node("stalled_reader")
    first = threading.Event()

    def never_returns(msg):
        # The first message proves the subscriptions matched and data flowed; then this callback blocks the
        # process's only executor thread forever, so no subscription of this process takes another message.
        if not first.is_set():
            first.set()
            print("STALLED", flush=True)
        threading.Event().wait()

    profiles = [QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.VOLATILE),
                QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.VOLATILE)]
    for topic in sys.argv[1:]:
        msg_type = MarkerArray if topic.endswith("/markers") else PoseArray
        for qos in profiles:
            node.create_subscription(msg_type, topic, never_returns, qos)
    rclpy.spin(node)
""")


def test_a_subscriber_that_never_reads_does_not_slow_the_tick(start_node, probe, tmp_path):
    """Another process subscribes to the big topics (the 3,000-boid flock's poses, the markers, the body
    poses) with RELIABLE readers, KEEP_LAST(1) and KEEP_ALL, and never reads: its only callback blocks
    forever (phase 1: DDS still receives and acknowledges into the reader's history, nobody takes), then the
    whole process is frozen with SIGSTOP (phase 2: it acknowledges nothing and drains no shared-memory port:
    a hung consumer).  The node must keep ticking at dt throughout (never blocked in ``publish``), its memory
    must not grow with what the consumer leaves unread, and a reader that does read (this probe) still gets
    the flock's poses.  The tick rates of the phases are printed, not bounded: a rate bound flakes on a busy
    2-core machine; the writer QoS below is what guarantees that nothing waits for the stalled reader.

    Why a stalled reliable reader cannot hold up the publisher: the node's state topics are published
    RELIABLE with KEEP_LAST(10) history on the writer (``cgp_sim_ros.ros.qos.STATE_QOS``; /clock is
    KEEP_LAST(1)).  A reliable writer keeps each sample for retransmission until every matched reader has
    acknowledged it.  With KEEP_ALL it would keep every sample a frozen reader never acknowledges (memory
    growing with the stall) and, once its resource limits are reached, ``publish`` would block for up to
    max_blocking_time; with KEEP_LAST a new sample simply replaces the oldest in the writer's history,
    acknowledged or not.  So ``publish`` never waits for a reader: the slow reader misses samples (it sees
    gaps) instead of slowing everyone, and the writer's memory is bounded by its depth.  (Checked by hand:
    with STATE_QOS switched to KEEP_ALL, the node's RSS grows by ~15 MB/s during phase 2 and this test fails
    on the memory bound; Fast DDS' KEEP_ALL limits are not reached within its 4 s, so the rate alone would
    not show it.)
    """
    scene = write_scene(tmp_path / "big_flock.yaml", BIG_FLOCK_SCENE)
    node = start_node("--scene", scene)
    clock = probe.subscribe("/clock", Clock)
    flock = probe.subscribe("/cgp_sim/flocks/school/poses", PoseArray, raw=True)  # raw: cheap to receive
    wait_ticking(probe, node, clock, 60)
    process = psutil.Process(node.proc.pid)

    t0 = time.monotonic()
    probe.spin_for(3.0)
    baseline = clock_rate(clock, t0, time.monotonic())

    topics = ["/cgp_sim/flocks/school/poses", "/cgp_sim/markers", "/cgp_sim/bodies/poses"]
    reader = PeerProcess(STALLED_READER, topics, tmp_path / "stalled_reader.log")
    try:
        probe.spin_until(lambda: reader.printed("STALLED"), 30,
                         "the other process's reader to receive its first message and stall")
        probe.spin_until(lambda: all(probe.node.count_subscribers(t) >= 2 for t in topics), 10,
                         "the stalled reader's subscriptions in the graph")
        rates, rss = {}, []
        for phase in ("blocked callback", "stopped process"):
            if phase == "stopped process":
                reader.proc.send_signal(signal.SIGSTOP)
            start = time.monotonic()
            ticks_before, flock_before = len(clock.messages), len(flock.messages)
            # the node ticks on and the probe keeps receiving the flock: 120 ticks (2 s at 60 Hz) within a
            # generous deadline, with memory sampled all along
            while len(clock.messages) < ticks_before + 120 or len(flock.messages) < flock_before + 60:
                assert time.monotonic() - start < 60, (
                    f"{phase}: only {len(clock.messages) - ticks_before} ticks and "
                    f"{len(flock.messages) - flock_before} flock messages in 60 s:\n{node.log()[-3000:]}")
                probe.spin_for(0.25)
                rss.append(process.memory_info().rss)
            rates[phase] = clock_rate(clock, start, time.monotonic())
            assert reader.proc.poll() is None, "the stalled reader died: nothing was tested"
    finally:
        reader.stop()

    log = node.log()
    print(f"slow consumer: {baseline:.1f} ticks/s before, "
          + ", ".join(f"{rate:.1f} with a {phase}" for phase, rate in rates.items())
          + f"; node RSS {min(rss) / 2**20:.1f}..{max(rss) / 2**20:.1f} MB while stalled")
    assert node.alive(), log
    assert max(rss) - rss[0] < 20 * 2**20, [r // 2**20 for r in rss]
    assert_clock_advances_by_dt(clock.messages, min_count=240)


# ---- shutdown from any state ------------------------------------------------------------------------------


def assert_bag_finished(bag) -> dict:
    """The bag a stopped node left: a finished MCAP (summary, statistics, footer) that mcap's indexed reader
    reads without recovery, rosbags' AnyReader reads and deserializes (every schema checked against its type
    hash), and a metadata.yaml whose counts are what the file holds.  Returns {topic: [(log time, message)]}."""
    files = sorted(p.name for p in bag.iterdir())
    (mcap_file,) = sorted(bag.glob("*.mcap"))
    assert files == sorted([mcap_file.name, "metadata.yaml"]), files
    with open(mcap_file, "rb") as f:
        reader = make_reader(f)  # the seeking reader: summary and indexes, no stream recovery
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None, "no summary: the file was not finished"
        count = sum(1 for _ in reader.iter_messages())
    assert count == summary.statistics.message_count > 0
    _, messages = read_bag(bag)
    assert sum(len(v) for v in messages.values()) == count
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["message_count"] == count
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert {topic: n for topic, n in counts.items() if n} == {topic: len(v) for topic, v in messages.items()}
    return messages


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("state", ["running", "paused", "just_stepped", "step_in_flight"])
def test_shutdown_from_any_state_is_clean(start_node, probe, tmp_path, state, signum):
    """A node recording a bag, stopped by a signal while running, while paused, right after a ~/step, or with
    a ~/step request sent just before the signal (served or not, whichever comes first: the signal only sets a
    flag the executor loop checks between callbacks, so a tick is never cut in half): exit status 0 within a
    deadline, no traceback or error, a finished bag (mcap's indexed reader without recovery, rosbags,
    metadata.yaml's counts) that holds every tick from the first one on, once on every state topic (no gaps:
    nothing lost) and, paused, exactly up to the tick where the node stood — one more if and only if the bag's
    audit trail (~/events) says the in-flight step was served.  (zero_g: its bag is quick to read back; what
    is tested does not depend on the scene.)"""
    bag = tmp_path / "bag"
    clock = probe.subscribe("/clock", Clock)
    node = start_node("--scene", "zero_g", "--bag", str(bag))
    wait_ticking(probe, node, clock, 30)
    stood_at = None  # the tick the node stands still at when the signal comes (paused states)
    if state != "running":
        pause(probe, True)
    if state == "just_stepped":
        for _ in range(3):
            response = step(probe)
        stood_at = int(response.message.split("(tick ")[1].rstrip(")"))
    elif state == "step_in_flight":
        probe.client(Trigger, "/cgp_sim/step").call_async(Trigger.Request())  # its reply is not waited for
    node.send(signum)
    assert node.wait(15) == 0, node.log()  # the deadline: a stop that hangs fails here
    log = node.log()
    assert "Traceback" not in log and "[ERROR]" not in log, log
    assert f"cgp-sim: bag in {bag} " in log, log

    messages = assert_bag_finished(bag)
    ticks = [tick(m) for _, m in messages["/clock"]]
    assert ticks == list(range(1, len(ticks) + 1)), "the bag's /clock has gaps or repeats"
    assert {tick(m) for m in clock.messages} <= set(ticks)  # the live view is a subset
    for topic in ("/cgp_sim/bodies/poses", "/cgp_sim/bodies/box/odom", "/cgp_sim/flocks/birds/poses",
                  "/cgp_sim/markers"):
        assert [t // DT_NS for t, _ in messages[topic]] == ticks, topic  # log time = the tick's sim time
    events = [json.loads(m.data) for _, m in messages.get("/cgp_sim/events", [])]
    if state in ("paused", "step_in_flight"):
        (paused,) = [e for e in events if e.get("name") == "pause"]
        stood_at = round(paused["time"] * 1e9) // DT_NS
        if any(e.get("name") == "step" for e in events[events.index(paused):]):
            stood_at += 1  # the step was served before the node stopped
    if stood_at is not None:
        assert ticks[-1] == stood_at, f"the bag ends at tick {ticks[-1]}, the node stood at {stood_at}"
    else:
        assert len(ticks) >= 30


# ---- bag directories --------------------------------------------------------------------------------------


def tree(root) -> list[str]:
    """Every file and directory under ``root``, relative, sorted."""
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


@pytest.mark.parametrize("case", ["beneath_a_regular_file", "name_too_long"])
def test_unwritable_bag_directory_is_a_clear_error_and_the_simulation_goes_on(start_node, probe, tmp_path, case):
    """A bag path that cannot be created: beneath a regular file (ENOTDIR; tests run as root, so permissions
    would not stop a write), or with a name longer than the file system's NAME_MAX (ENAMETOOLONG, which used to
    escape as a traceback from the start-up check).  Issue 6: "disk full or unwritable directory: a clear error;
    the simulation and publishing go on" — so not a start-up failure: the node logs one error naming the path
    and the reason, says it is not recording, simulates and publishes on, stops cleanly with status 0, and
    leaves nothing on disk."""
    root = tmp_path / "out"
    root.mkdir()
    if case == "beneath_a_regular_file":
        (root / "a_file").write_text("not a directory\n")
        bag, reason = root / "a_file" / "bag", "Not a directory"
    else:
        bag, reason = root / ("x" * 300) / "bag", "File name too long"
    before = tree(root)
    clock = probe.subscribe("/clock", Clock)
    fish = probe.subscribe("/cgp_sim/flocks/fish/poses", PoseArray)
    node = start_node("--scene", "default", "--bag", str(bag))
    wait_ticking(probe, node, clock, 60)
    probe.wait_for_messages("/cgp_sim/flocks/fish/poses", 30, timeout=10)
    log = node.log()
    assert node.alive(), log
    (error,) = [line for line in log.splitlines() if "[ERROR]" in line]
    assert f"recording failed: cannot record the bag in '{bag}': {reason}" in error, error
    assert "the simulation goes on" in error and "NOT recording" in log and "recording to" not in log, log
    assert_clock_advances_by_dt(clock.messages, min_count=60)
    assert all(len(m.poses) == 300 for m in fish.messages)

    node.send(signal.SIGINT)
    assert node.wait(15) == 0, node.log()
    log = node.log()
    assert "Traceback" not in log, log
    assert "cgp-sim: no bag recorded" in log and reason in log.splitlines()[-1], log
    assert tree(root) == before  # nothing created, nothing left behind


def test_bag_files_are_written_only_inside_the_resolved_bag_directory(start_node, probe, tmp_path):
    """The bag parameter is resolved once, as the OS resolves it (``~``, ``..``, symlinks), and everything
    the recording writes lands in that directory: ``out/new/../bag`` is ``out/bag``, and ``out/new`` is not
    created on the way (a lexical ``mkdir -p out/new/../bag`` would create it); through a symlink,
    ``out/link/../bag`` is where ``link``'s target's parent is, as a shell would have it.  After a short
    recorded run each bag directory holds one ``.mcap`` file and ``metadata.yaml`` and nothing else (no
    temporary file), the log names the resolved directory, and nothing else appeared anywhere under tmp.  An
    existing, non-empty directory reached through ``..`` is refused at start-up (status 2, naming the resolved
    path) and left as it was."""
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    (elsewhere / "target").mkdir(parents=True)
    (out / "link").symlink_to(elsewhere / "target")
    (out / "old").mkdir()
    (out / "old" / "keep.txt").write_text("an earlier recording\n")
    cases = [(out / "new" / ".." / "bag", out / "bag"),
             (out / "link" / ".." / "bag", elsewhere / "bag")]
    nodes = [start_node("--scene", "zero_g", "--duration", "1.0", "--bag", str(given),
                        "--ros-args", "-r", f"__ns:=/n{i}") for i, (given, _) in enumerate(cases)]
    refused = start_node("--scene", "zero_g", "--bag", str(out / "new" / ".." / "old"))
    assert refused.wait(30) == 2, refused.log()
    assert f"cgp-sim: bag: '{out / 'old'}' already exists and is not empty" in refused.log(), refused.log()
    for node in nodes:
        assert node.wait(30) == 0, node.log()
    assert tree(tmp_path) == sorted(
        ["out", "out/bag", "out/bag/bag_0.mcap", "out/bag/metadata.yaml", "out/link", "out/old",
         "out/old/keep.txt", "elsewhere", "elsewhere/bag", "elsewhere/bag/bag_0.mcap",
         "elsewhere/bag/metadata.yaml", "elsewhere/target"]
        + [p.name for p in tmp_path.glob("node*.log")])
    assert (out / "old" / "keep.txt").read_text() == "an earlier recording\n"
    for node, (_given, resolved) in zip(nodes, cases):
        log = node.log()
        assert f"recording to {resolved}\n" in log, log
        assert f"cgp-sim: bag in {resolved} " in log, log
        assert_bag_finished(resolved)

"""Issue 8, long run: the default scene plus a 10,000-boid flock, recorded to a bag, for
``CGP_SIM_SOAK_SECONDS`` (default 900 = 15 min) of wall time at real time.  Marked ``soak``: skipped by
``make test``, run by ``make soak`` (``CGP_SIM_SOAK_SECONDS=60 make soak`` for a short one).  Issue 27 added two
clients in other processes for the whole run: one spawns a body (``visitor``, a sphere far from the scene's
bodies and flocks) every second and deletes it half a second later (simulation_interfaces), the other sends
``~/apply_wrench`` commands on it at 20 Hz (rejected, and summarized, while it does not exist).

What must hold for the whole run, observed from this process over DDS and from the node's /proc entry:

- the node stays alive and keeps ticking, and stops cleanly on SIGINT at the end (status 0, no traceback, no
  error logged);
- no NaN / inf in anything it publishes (every odometry message; every 30th message of the body poses and
  of both flocks' poses, decoded straight from the CDR bytes with numpy so that a 10k-pose message costs
  this process almost nothing);
- the rigid bodies' energy stays bounded (see :func:`test_soak_default_scene_and_10k_boids`);
- memory is flat: after the warm-up, the node's RSS stays within 2 % of what it was at the end of the
  warm-up (median of the last samples against the median of the warm-up's last samples); its parts
  (/proc/<pid>/status: RssAnon, RssFile, RssShmem) are printed at both ends, so a drift says where it is;
- the clients: every spawn and delete answered OK (but for the first seconds of discovery), the wrench
  commands taken;
- the bag is readable at the end: every file finished (summary), metadata.yaml's counts are what the files
  hold, /clock has one message per tick from the first (nothing lost), rosbags opens the directory and
  deserializes its last second of /clock.

Disk: the bag takes ~35 MB/s of wall time (mostly the 10k flock's 560 kB PoseArray every tick; its markers
are published every 30 ticks, ``--markers-every`` being the level-of-detail option for huge flocks, or the bag
would be twice that), ~32 GB for the default 15 min; it is split into 2 GB files, checked, and its .mcap files
deleted at the end, passed or failed (metadata.yaml and the node's log stay in the test's tmp directory).
"""

from __future__ import annotations

import os
import shutil
import signal
import statistics
import textwrap
import time

import numpy as np
import psutil
import pytest
import yaml
from geometry_msgs.msg import PoseArray
from mcap.reader import make_reader
from nav_msgs.msg import Odometry
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from ros_probe import PeerProcess
from rosbags.highlevel import AnyReader
from rosgraph_msgs.msg import Clock

from cgp_core.scene import builtin_scene_dir, load_scene

SOAK_SECONDS = float(os.environ.get("CGP_SIM_SOAK_SECONDS", "900"))
RATE_HZ = 60.0
DT_NS = round(1e9 / RATE_HZ)
SAMPLE_S = 2.0  # RSS sampling period
#: warm-up, after which the RSS must stay flat: the first 5 min or 10 % of the run, whichever is longer (a
#: try-out shorter than 20 min: its first quarter).  Numpy's temporaries, the flock's neighbour grid, Fast DDS'
#: pools and the bag writer's buffers reach their working size in it (measured: ~15 s of simulated time for
#: the flock alone, in-process).
#: Issue 27's hour: the heap (RssAnon) reached its working size ~5 min in (150.9 -> 157.0 -> 152.6 MB, then
#: 152.6..153.9 for the rest of the hour; RssFile and RssShmem never moved): a 90 s warm-up ended on the way
#: there, which is what the 15-minute soak's +3.5 % was.  Hence at least 5 min (a quarter of a shorter run).
WARMUP_S = max(0.1 * SOAK_SECONDS, min(300.0, 0.25 * SOAK_SECONDS))
RSS_TOLERANCE = 0.02
CHECK_EVERY = 30  # decode every 30th message of the pose arrays
BAG_SPLIT_BYTES = 2_000_000_000
BAG_BYTES_PER_S = 36e6  # what the disk must hold per second of run (measured: 33-35 MB/s)
#: of which the 10k flock's poses (560 kB every tick); a run too long for the disk records them every N ticks
#: (the node's bag_flock_poses_every, its level of detail for the bag), the smallest N that fits
FLOCK_POSES_BYTES_PER_S = 33.6e6

#: the 10k flock: spawned at the density of the default flock's steady state (~0.52 boids/m³, as
#: benchmarks/scenes/tick_15k.yaml: 10,000 boids in 34 x 34 x 17 m), so that it does not spend the first
#: minute contracting from a sparse cloud (its neighbour lists, hence its working memory, grow while it does)
SWARM = {"name": "swarm", "count": 10_000, "model": "sphere", "boid_size": 0.3,
         "spawn": {"center": [0, 0, 9.5], "extent": [34, 34, 17]},
         "bounds": {"min": [-30, -30, 0.5], "max": [30, 30, 30.5]}, "seed": 5}

RELIABLE_SHALLOW = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2, reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.VOLATILE)


def pose_rows(data: bytes) -> np.ndarray:
    """The (n, 7) poses of a CDR-serialized geometry_msgs/PoseArray, without building rclpy objects:
    encapsulation (4), stamp (8), frame_id (u32 length incl. NUL + bytes), the count on 4 bytes, then the
    poses on 8 (offsets counted after the encapsulation) — they are the message's last 56·n bytes."""
    frame_len = int.from_bytes(data[12:16], "little")
    offset = 12 + frame_len
    offset += -offset % 4
    count = int.from_bytes(data[4 + offset:8 + offset], "little")
    assert 8 + offset + 56 * count <= len(data), "malformed PoseArray"
    return np.frombuffer(data, dtype="<f8", count=7 * count, offset=len(data) - 56 * count).reshape(count, 7)


class Energy:
    """Kinetic + potential energy of the movable bodies from their odometry (pose in world, twist in the body
    frame, nav_msgs' convention): E = Σ ½ m |v|² + ½ ωᵀ I_body ω + m g·(−z) with g along −z."""

    def __init__(self, scene):
        self.model, state = scene.build_bodies()
        self.g = -float(scene.world.gravity[2])
        self.index = {name: i for i, name in enumerate(self.model.names)}
        self.movable = [name for name, fixed in zip(self.model.names, self.model.fixed) if not fixed]
        # the initial state (kinetic energy is frame-independent: ½ m |v|² + ½ ω·L, both in world axes)
        v, w = state.linear_velocity(self.model), state.angular_velocity(self.model)
        self.initial = {name: 0.5 * self.model.mass[i] * v[i] @ v[i] + 0.5 * w[i] @ state.angular_momentum[i]
                        + self.model.mass[i] * self.g * state.position[i][2]
                        for name in self.movable for i in [self.index[name]]}

    def of(self, name: str, msg) -> float:
        i = self.index[name]
        p, t = msg.pose.pose.position, msg.twist.twist
        v = np.array([t.linear.x, t.linear.y, t.linear.z])
        w = np.array([t.angular.x, t.angular.y, t.angular.z])
        m = self.model.mass[i]
        return 0.5 * m * v @ v + 0.5 * w @ self.model.inertia_body[i] @ w + m * self.g * p.z


def stamp_ns(t) -> int:
    return t.sec * 1_000_000_000 + t.nanosec


def rss_parts(pid: int) -> dict[str, int]:
    """RssAnon, RssFile, RssShmem of a process [kB] (/proc/<pid>/status): where its resident memory is."""
    with open(f"/proc/{pid}/status") as f:
        return {k: int(v.split()[0]) for k, v in (line.split(":", 1) for line in f) if k in ("RssAnon", "RssFile",
                                                                                                   "RssShmem")}


#: issue 27's clients: spawn a visitor body every second and delete it half a second later ...
SPAWNER = textwrap.dedent("""
    import sys, time
    import rclpy
    from simulation_interfaces.msg import Result
    from simulation_interfaces.srv import DeleteEntity, SpawnEntity

    rclpy.init()
    node = rclpy.create_node("soak_spawner")
    spawn = node.create_client(SpawnEntity, "/cgp_sim/spawn_entity")
    delete = node.create_client(DeleteEntity, "/cgp_sim/delete_entity")
    spawn.wait_for_service(timeout_sec=60)
    delete.wait_for_service(timeout_sec=60)

    def call(client, request):
        future = client.call_async(request)
        rclpy.spin_until_future_complete(node, future, timeout_sec=10)
        return future.result()

    ok = failed = 0
    end = time.monotonic() + float(sys.argv[1])
    while time.monotonic() < end:
        started = time.monotonic()
        request = SpawnEntity.Request(name="visitor", resource_string="body: {shape: sphere, radius: 0.3, mass: 2}")
        request.initial_pose.pose.position.x, request.initial_pose.pose.position.y = 50.0, 50.0
        request.initial_pose.pose.position.z = 3.0
        spawned = call(spawn, request)
        time.sleep(0.5)
        deleted = call(delete, DeleteEntity.Request(entity="visitor"))
        good = spawned is not None and spawned.result.result == Result.RESULT_OK and deleted is not None \
            and deleted.result.result == Result.RESULT_OK
        ok, failed = ok + good, failed + (not good)
        if not good:
            print("FAILED", spawned and spawned.result.error_message, deleted and deleted.result.error_message,
                  flush=True)
        time.sleep(max(0.0, 1.0 - (time.monotonic() - started)))
    print(f"SPAWNER ok {ok} failed {failed}", flush=True)
""")

#: ... and push it with wrench commands at 20 Hz
WRENCHER = textwrap.dedent("""
    import sys, time
    import rclpy
    from cgp_sim_msgs.msg import ApplyWrench

    rclpy.init()
    node = rclpy.create_node("soak_wrencher")
    publisher = node.create_publisher(ApplyWrench, "/cgp_sim/apply_wrench", 10)
    sent = 0
    end = time.monotonic() + float(sys.argv[1])
    while time.monotonic() < end:
        msg = ApplyWrench(body="visitor")
        msg.wrench.force.z = 30.0
        msg.wrench.torque.x = 0.5
        publisher.publish(msg)
        sent += 1
        time.sleep(0.05)
    print(f"WRENCHER sent {sent}", flush=True)
""")


@pytest.mark.soak
@pytest.mark.timeout(SOAK_SECONDS + 600)
def test_soak_default_scene_and_10k_boids(start_node, probe, tmp_path):
    """Energy bound, explained: E0 is the bodies' energy in the scene's initial state (~6,840 J, nearly all
    of it the potential energy of the bodies dropped from 3-6 m).  Nothing in the world adds energy to the
    bodies: gravity is conservative, and the implicit midpoint integrator is exact for free fall under
    constant gravity and conserves the torque-free kinetic energy of rotation (a quadratic invariant); contacts
    only take energy away (restitution ≤ 1, Coulomb friction); no wrench is applied; the boids steer around
    the bodies and never push them.  What can add a little is the penetration recovery, which lifts a resting
    body by at most its penetration depth (millimetres: m·g·δ ≈ 127 kg · 9.81 · 0.005 m ≈ 6 J for the heavy
    capsule).  So the margin is 1 % of E0 (~68 J, the ball lifted by 3.5 m: far above that error, far below
    any blow-up); asserted twice: never above E0 + margin, and, once the bodies have settled (after the
    warm-up), never above the settled energy + margin (no slow creep of energy into resting bodies).
    """
    free = shutil.disk_usage(tmp_path).free
    flock_every = next((n for n in range(1, 31) if (BAG_BYTES_PER_S - FLOCK_POSES_BYTES_PER_S * (1 - 1 / n))
                        * SOAK_SECONDS * 1.1 < free), 30)
    if flock_every > 1:
        print(f"\nsoak: recording the flocks' poses every {flock_every} ticks (the disk has {free / 1e9:.0f} GB)")
    needed = (BAG_BYTES_PER_S - FLOCK_POSES_BYTES_PER_S * (1 - 1 / flock_every)) * SOAK_SECONDS
    if free < needed * 1.1:
        pytest.fail(f"the soak's bag needs ~{needed / 1e9:.0f} GB; {free / 1e9:.0f} GB "
                    f"free in {tmp_path}")
    scene_data = yaml.safe_load((builtin_scene_dir() / "default.yaml").read_text())
    scene_data["description"] = "the default scene plus a 10,000-boid flock of spheres (tests/test_soak.py)"
    scene_data["flocks"].append(SWARM)
    scene_path = tmp_path / "default_10k.yaml"
    scene_path.write_text(yaml.safe_dump(scene_data, sort_keys=False))
    energy = Energy(load_scene(scene_path))
    e0 = sum(energy.initial.values())
    margin = 0.01 * e0

    # ---- observers: keep numbers, not messages (a 15-minute run would not fit in memory otherwise)
    ticks: list[tuple[float, int]] = []  # (wall time, tick) of every /clock received
    body_energy: dict[str, tuple[int, float]] = {}  # the latest (tick, E) of each body
    totals: list[tuple[float, int, float]] = []  # (wall, tick, total E) whenever every body has reported it
    counts = {"odometry": 0, "pose arrays": 0, "pose arrays checked": 0, "poses checked": 0}
    non_finite: list[str] = []
    node_api = probe.node
    node_api.create_subscription(Clock, "/clock",
                                 lambda m: ticks.append((time.monotonic(), stamp_ns(m.clock) // DT_NS)),
                                 RELIABLE_SHALLOW)

    def on_odometry(name):
        def callback(msg):
            counts["odometry"] += 1
            values = [msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.position.z,
                      msg.pose.pose.orientation.w, msg.twist.twist.linear.x, msg.twist.twist.linear.y,
                      msg.twist.twist.linear.z, msg.twist.twist.angular.x, msg.twist.twist.angular.y,
                      msg.twist.twist.angular.z]
            if not np.isfinite(values).all():
                non_finite.append(f"{name} odometry at {stamp_ns(msg.header.stamp)} ns")
                return
            tick = stamp_ns(msg.header.stamp) // DT_NS
            body_energy[name] = (tick, energy.of(name, msg))
            if len(body_energy) == len(energy.movable) and len({t for t, _ in body_energy.values()}) == 1:
                totals.append((time.monotonic(), tick, sum(e for _, e in body_energy.values())))
        return callback

    for name in energy.movable:
        node_api.create_subscription(Odometry, f"/cgp_sim/bodies/{name}/odom", on_odometry(name), 100)

    def on_pose_array(topic):
        seen = [0]

        def callback(data: bytes):
            seen[0] += 1
            counts["pose arrays"] += 1
            if seen[0] % CHECK_EVERY != 1:
                return
            rows = pose_rows(data)
            counts["pose arrays checked"] += 1
            counts["poses checked"] += len(rows)
            if seen[0] == 1:  # the numpy decoding is what rclpy decodes
                msg = deserialize_message(data, PoseArray)
                p = msg.poses[-1]
                assert len(msg.poses) == len(rows) and rows[-1].tolist() == [
                    p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y, p.orientation.z,
                    p.orientation.w]
            if not np.isfinite(rows).all():
                non_finite.append(f"{topic}: {int((~np.isfinite(rows)).any(axis=1).sum())} non-finite poses")
        return callback

    pose_topics = ["/cgp_sim/bodies/poses", "/cgp_sim/flocks/fish/poses", "/cgp_sim/flocks/swarm/poses"]
    for topic in pose_topics:
        node_api.create_subscription(PoseArray, topic, on_pose_array(topic), RELIABLE_SHALLOW, raw=True)

    # ---- the run
    bag = tmp_path / "bag"
    node = start_node("--scene", str(scene_path), "--bag", str(bag), "--markers-every", "30",
                      "--bag-flock-poses-every", str(flock_every),
                      "--bag-max-size", str(BAG_SPLIT_BYTES))
    try:
        probe.spin_until(lambda: len(ticks) >= 60 and len(totals) > 0, 60, "the node's first second")
        process = psutil.Process(node.proc.pid)
        clients = [PeerProcess(code, [SOAK_SECONDS], tmp_path / f"{name}.log")
                   for name, code in (("spawner", SPAWNER), ("wrencher", WRENCHER))]
        start = time.monotonic()
        parts: dict[str, dict] = {}
        rss: list[tuple[float, int]] = []  # (seconds into the run, bytes)
        while (elapsed := time.monotonic() - start) < SOAK_SECONDS:
            probe.spin_for(min(SAMPLE_S, SOAK_SECONDS - elapsed))
            assert node.alive(), f"the node died after {elapsed:.0f} s:\n{node.log()[-4000:]}"
            rss.append((time.monotonic() - start, process.memory_info().rss))
            if "warm" not in parts and rss[-1][0] > WARMUP_S:
                parts["warm"] = rss_parts(node.proc.pid)
            assert not non_finite, non_finite[:10]
        parts["end"] = rss_parts(node.proc.pid)
        outputs = [client.proc.wait(60) == 0 and client.stop() for client in clients]
        assert all(outputs), [client.output()[-2000:] for client in clients]
        spawner = next(line for line in outputs[0].splitlines() if line.startswith("SPAWNER")).split()
        wrencher = next(line for line in outputs[1].splitlines() if line.startswith("WRENCHER")).split()
        spawned_ok, spawned_failed, wrenches_sent = int(spawner[2]), int(spawner[4]), int(wrencher[2])
        last_tick_seen = ticks[-1][1]
        probe.spin_until(lambda: ticks[-1][1] > last_tick_seen, 10, "the node to be still ticking")

        node.send(signal.SIGINT)
        assert node.wait(120) == 0, node.log()[-4000:]
        log = node.log()
        assert "Traceback" not in log and "[ERROR]" not in log, log[-4000:]
        assert not non_finite, non_finite[:10]

        # ---- memory: flat after the warm-up
        warm = ([b for t, b in rss if t <= WARMUP_S + 0.5 * SAMPLE_S] or [rss[0][1]])[-5:]
        end = [b for _, b in rss[-5:]]
        warm_mb, end_mb = statistics.median(warm) / 2**20, statistics.median(end) / 2**20
        after = [b / 2**20 for t, b in rss if t > WARMUP_S]

        # ---- energy
        settled = [e for w, _, e in totals if w - start <= WARMUP_S][-1]
        late = [e for w, _, e in totals if w - start > WARMUP_S] or [settled]
        wall_ticks = ticks[-1][1] - ticks[0][1]
        wall = ticks[-1][0] - ticks[0][0]
        print(f"\nsoak: {SOAK_SECONDS:g} s of wall time, tick {ticks[-1][1]} reached "
              f"({ticks[-1][1] / RATE_HZ:.0f} s simulated; {wall_ticks / wall:.1f} ticks/s); "
              f"{counts['odometry']} odometry messages, {counts['pose arrays']} pose arrays received, "
              f"{counts['pose arrays checked']} of them ({counts['poses checked']} poses) checked: all finite\n"
              f"soak: node RSS {rss[0][1] / 2**20:.1f} MB at {rss[0][0]:.0f} s, {warm_mb:.1f} MB at the end of the "
              f"{WARMUP_S:g} s warm-up (median), {end_mb:.1f} MB at the end (median of the last 5 samples), "
              f"parts [kB] at the warm-up's end {parts.get('warm')} and at the end {parts['end']}, "
              f"{min(after):.1f}..{max(after):.1f} MB after the warm-up ({len(rss)} samples; every "
              f"{10 * SAMPLE_S:g} s: {' '.join(str(b >> 20) for _, b in rss[::10])})\n"
              f"soak: energy E0 {e0:.1f} J, max {max(e for _, _, e in totals):.1f} J, settled {settled:.1f} J, "
              f"max after the warm-up {max(late):.1f} J (margin {margin:.1f} J)")
        print(f"soak: clients: {spawned_ok} spawn+delete cycles OK, {spawned_failed} failed; {wrenches_sent} "
              "wrench commands sent")
        # a cycle is 1 s when the machine is idle; under load its two round trips take longer (the 1-hour run of
        # issue 27, at load ~5 on 2 cores: 2,363 cycles, 1.5 s each): what must hold is that none failed
        assert spawned_ok >= SOAK_SECONDS / 4 and spawned_failed <= 2, (spawned_ok, spawned_failed)
        assert abs(end_mb - warm_mb) <= RSS_TOLERANCE * warm_mb, \
            f"RSS {warm_mb:.1f} MB -> {end_mb:.1f} MB: {[(round(t), b >> 20) for t, b in rss]}"
        assert max(e for _, _, e in totals) <= e0 + margin
        assert max(late) <= settled + margin

        # ---- the bag
        meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        files = sorted(bag.glob("*.mcap"), key=lambda p: int(p.stem.rsplit("_", 1)[1]))
        assert [p.name for p in files] == meta["relative_file_paths"]
        total, clock_count = 0, 0
        for path in files:
            with open(path, "rb") as f:
                summary = make_reader(f).get_summary()
            assert summary is not None and summary.statistics is not None, f"{path.name} was not finished"
            total += summary.statistics.message_count
            clock_channel = next(c.id for c in summary.channels.values() if c.topic == "/clock")
            clock_count += summary.statistics.channel_message_counts.get(clock_channel, 0)
        assert meta["message_count"] == total
        topic_counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
        assert topic_counts["/clock"] == clock_count
        last_tick = ticks[-1][1]
        with AnyReader([bag]) as reader:
            assert reader.message_count == total
            # the last simulated second, deserialized: /clock ends at the last tick, one message per tick
            clocks = [c for c in reader.connections if c.topic == "/clock"]
            tail = [reader.deserialize(raw, c.msgtype)
                    for c, _, raw in reader.messages(connections=clocks, start=reader.end_time - 10**9)]
        bag_ticks = [stamp_ns(m.clock) // DT_NS for m in tail]
        assert bag_ticks == list(range(bag_ticks[0], bag_ticks[-1] + 1)) and bag_ticks[-1] >= last_tick
        assert clock_count == bag_ticks[-1], "the bag's /clock does not hold every tick from the first"
        print(f"soak: bag {sum(p.stat().st_size for p in files) / 1e9:.2f} GB in {len(files)} file(s), "
              f"{total} messages, ticks 1..{bag_ticks[-1]}")
    finally:
        for path in bag.glob("*.mcap"):
            path.unlink()

"""Issue 15, live view: the node's Foxglove WebSocket server, end to end.

The node runs as its own process (``cgp-sim --foxglove true --foxglove-port 0``: a free port, read from its
log) and is observed by a client written here from the Foxglove protocol (``tests/foxglove_client.py``,
subprotocol ``foxglove.sdk.v1``) and, where DDS is the reference, by a DDS subscriber in this process.  The
``zero_g`` scene: ``box`` (2 kg, at rest at (0, 0, 2), no gravity), ``spinner`` and the flock ``birds``.
Expected motions are closed forms (Δv = F dt / m for a one-tick force).
"""

from __future__ import annotations

import json
import math
import re
import socket
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from cgp_sim_msgs.msg import Contacts, FlockStats
from foxglove_client import FoxgloveClient, ServiceCallFailed
from geometry_msgs.msg import PoseArray, WrenchStamped
from mcap.reader import make_reader
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

DT_NS = round(1e9 / 60)
DT = DT_NS * 1e-9  # the tick the world integrates over: whole nanoseconds (cgp_core.world)
BOX_MASS = 2.0
#: what the Foxglove app sends for a request without fields (std_srvs/Trigger): the CDR header alone
EMPTY_CDR_REQUEST = b"\x00\x01\x00\x00"
PUBLISHED = {
    "/clock": Clock,
    "/cgp_sim/bodies/poses": PoseArray,
    "/cgp_sim/bodies/box/odom": Odometry,
    "/cgp_sim/bodies/spinner/odom": Odometry,
    "/cgp_sim/flocks/birds/poses": PoseArray,
    "/cgp_sim/flocks/birds/stats": FlockStats,
    "/cgp_sim/contacts": Contacts,
    "/cgp_sim/markers": MarkerArray,
    "/cgp_sim/static_markers": MarkerArray,
    "/cgp_sim/events": String,
    "/tf": TFMessage,
    "/tf_static": TFMessage,
}
COMMAND_TOPICS = {"/cgp_sim/apply_wrench", "/cgp_sim/bodies/box/wrench", "/cgp_sim/bodies/spinner/wrench"}
SERVICES = {"/cgp_sim/reset": "std_srvs/srv/Trigger", "/cgp_sim/pause": "std_srvs/srv/SetBool",
            "/cgp_sim/step": "std_srvs/srv/Trigger", "/cgp_sim/clear_wrenches": "std_srvs/srv/Trigger"}


# ---- helpers --------------------------------------------------------------------------------------------


def foxglove_url(node, timeout: float = 30.0) -> str:
    """The ws:// URL the node prints at start-up (its port is chosen by the OS: --foxglove-port 0)."""
    deadline = time.monotonic() + timeout
    while True:
        match = re.search(r"Foxglove live view on ws://localhost:(\d+)", node.log())
        if match:
            return f"ws://127.0.0.1:{match.group(1)}"
        if not node.alive() or time.monotonic() > deadline:
            raise AssertionError(f"the node printed no Foxglove URL; log:\n{node.log()[-3000:]}")
        time.sleep(0.05)


@pytest.fixture
def live(start_node, request):
    """start(*args) -> (node process, connected client); the clients are closed at teardown."""
    clients = []

    def start(*args: str):
        node = start_node("--scene", "zero_g", "--foxglove", "true", "--foxglove-port", "0", *args)
        client = FoxgloveClient(foxglove_url(node))
        clients.append(client)
        client.wait(lambda: client.server_info and len(client.channels) == len(PUBLISHED) + len(COMMAND_TOPICS)
                    and len(client.services) == len(SERVICES), 20, "the server's advertisements")
        return node, client

    yield start
    for client in clients:
        client.close()


def stamp_of(msg) -> int:
    t = msg.clock if isinstance(msg, Clock) else msg.markers[0].header.stamp if isinstance(msg, MarkerArray) \
        else msg.header.stamp
    return t.sec * 1_000_000_000 + t.nanosec


def padded(cdr: bytes) -> bytes:
    """A serialized message as a DDS reader gets it: Fast DDS pads the RTPS payload with zeros to a multiple
    of 4 bytes (the node publishes, records and shows in Foxglove the unpadded bytes)."""
    return cdr + bytes(-len(cdr) % 4)


def world_velocity(odom: Odometry) -> np.ndarray:
    """Odometry's twist is in the body frame (nav_msgs convention): rotate it into world axes."""
    from scipy.spatial.transform import Rotation

    q, v = odom.pose.pose.orientation, odom.twist.twist.linear
    return Rotation.from_quat([q.x, q.y, q.z, q.w]).apply([v.x, v.y, v.z])


def wrench_stamped(force, frame: str = "world") -> bytes:
    msg = WrenchStamped()
    msg.header.frame_id = frame
    msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = map(float, force)
    return serialize_message(msg)


def step(client: FoxgloveClient) -> str:
    response = deserialize_message(client.call("/cgp_sim/step", EMPTY_CDR_REQUEST), Trigger.Response)
    assert response.success, response.message
    return response.message


def pause(client: FoxgloveClient, on: bool) -> None:
    response = deserialize_message(client.call("/cgp_sim/pause", serialize_message(SetBool.Request(data=on))),
                                   SetBool.Response)
    assert response.success, response.message


def last_odom(client: FoxgloveClient, subscription: int, log_time: int | None = None,
              timeout: float = 20.0) -> Odometry:
    """The box odometry of tick ``log_time`` (default: the newest), from the WebSocket."""
    def find():
        got = client.messages[subscription]
        if log_time is None:
            return got[-1] if got else None
        return next((m for m in got if m[0] == log_time), None)
    found = client.wait(find, timeout, f"odometry at {log_time}")
    return deserialize_message(found[1], Odometry)


def events(client: FoxgloveClient, subscription: int) -> list[dict]:
    return [json.loads(deserialize_message(data, String).data) for _, data in client.received(subscription)]


def bag_messages(bag_dir) -> dict[str, list[bytes]]:
    out: dict[str, list[bytes]] = {}
    for path in sorted(bag_dir.glob("*.mcap")):
        with open(path, "rb") as f:
            for _, channel, message in make_reader(f).iter_messages():
                out.setdefault(channel.topic, []).append(message.data)
    return out


# ---- the tests ------------------------------------------------------------------------------------------


def test_channels_schemas_and_services_are_the_bags(live, tmp_path):
    """Every topic of the node is a cdr channel whose schema is the one the bag of the same run holds; the
    services carry their request / response definitions; only the foxglove.sdk.v1 subprotocol is accepted."""
    from rosbags.typesys import get_types_from_msg

    bag = tmp_path / "bag"
    node, client = live("--start-paused", "true", "--bag", str(bag))
    info = client.server_info
    assert {"clientPublish", "services", "time"} <= set(info["capabilities"])
    assert info["supportedEncodings"] == ["cdr", "json"]

    # A client offering only the old subprotocol is refused at the handshake; the server goes on serving.
    with pytest.raises(InvalidStatus) as refused, connect(client.url, subprotocols=["foxglove.websocket.v1"],
                                                          open_timeout=10):
        pass
    assert refused.value.response.status_code == 400
    pause(client, True)

    assert node.stop() == 0
    with open(next(bag.glob("*.mcap")), "rb") as f:
        summary = make_reader(f).get_summary()
    bag_channels = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
    channels = {c["topic"]: c for c in client.channels.values()}
    assert set(channels) == set(bag_channels) == set(PUBLISHED) | COMMAND_TOPICS
    for topic, channel in channels.items():
        schema = bag_channels[topic]
        assert (channel["encoding"], channel["schemaEncoding"]) == ("cdr", "ros2msg"), topic
        assert channel["schemaName"] == schema.name and re.fullmatch(r"\w+/msg/\w+", schema.name), topic
        assert channel["schema"] == schema.data.decode(), topic

    assert {name: s["type"] for name, s in client.services.items()} == SERVICES
    fields = {}
    for name, service in client.services.items():
        for part in ("request", "response"):
            schema = service[part]
            assert (schema["encoding"], schema["schemaEncoding"]) == ("cdr", "ros2msg")
            assert schema["schemaName"] == f"{service['type']}_{part.capitalize()}"
            msg_name = schema["schemaName"].replace("/srv/", "/msg/")  # rosbags parses messages
            parsed = get_types_from_msg(schema["schema"], msg_name)[msg_name]
            fields[(name, part)] = [f[0] for f in parsed[1]]
    assert fields[("/cgp_sim/pause", "request")] == ["data"]
    assert fields[("/cgp_sim/step", "request")] == []
    assert fields[("/cgp_sim/reset", "response")] == ["success", "message"]


def test_messages_are_the_dds_bytes_at_the_simulation_time(live, probe):
    """For the same tick, a Foxglove client gets exactly the bytes a DDS subscriber gets, logged at the tick's
    simulation time, which is also sent as a time message; while running, time advances by dt per tick."""
    topics = ["/clock", "/cgp_sim/bodies/poses", "/cgp_sim/bodies/box/odom", "/cgp_sim/flocks/birds/poses",
              "/cgp_sim/markers"]
    dds = {topic: probe.subscribe(topic, PUBLISHED[topic], raw=True) for topic in [*topics, "/cgp_sim/events"]}
    node, client = live("--start-paused", "true")
    subscriptions = {topic: client.subscribe(topic) for topic in [*topics, "/cgp_sim/events"]}
    for topic in topics:
        probe.wait_for_publisher(topic)

    # Step (from Foxglove) until the DDS subscriber has a message on every topic, then four more ticks.
    deadline = time.monotonic() + 30
    while not all(dds[t].messages for t in topics):
        assert time.monotonic() < deadline, "the DDS subscriber never matched"
        step(client)
        probe.spin_for(0.1)
    for _ in range(4):
        ticks = int(re.search(r"tick (\d+)", step(client)).group(1))
        probe.spin_for(0.1)  # /clock is keep-last-1: let each tick's clock reach the reader
    probe.spin_until(lambda: all(stamp_of(deserialize_message(dds[t].messages[-1], PUBLISHED[t])) == ticks * DT_NS
                                 for t in topics), 20, "the last tick over DDS")
    client.wait(lambda: all(client.messages[subscriptions[t]] and client.messages[subscriptions[t]][-1][0]
                            == ticks * DT_NS for t in topics), 20, "the last tick over the WebSocket")

    for topic in topics:
        over_ws = dict(client.received(subscriptions[topic]))
        # Subscribed before the first step (same socket, in order): every tick is there, at its time.
        assert sorted(over_ws) == [k * DT_NS for k in range(1, ticks + 1)], topic
        over_dds = {stamp_of(deserialize_message(m, PUBLISHED[topic])): bytes(m) for m in dds[topic].messages}
        common = set(over_dds) & set(over_ws)
        assert len(common) >= (1 if topic == "/clock" else 4) and ticks * DT_NS in common, topic
        for stamp in common:
            assert padded(over_ws[stamp]) == over_dds[stamp], f"{topic} at {stamp} ns: the bytes differ"
    # ~/events (one line per step here), logged at the time they happened.  (The start-up event, the level of
    # detail, went out before this client subscribed: it is the service calls that are compared.)

    def service_events():
        return {bytes(m) for m in dds["/cgp_sim/events"].messages if b'"event":"service"' in bytes(m)}

    probe.spin_until(lambda: len(service_events()) >= 4, 20, "events over DDS")
    over_ws = [data for _, data in client.received(subscriptions["/cgp_sim/events"])]
    assert service_events() <= {padded(data) for data in over_ws}
    # Every tick's time was sent as a time message (the app's clock; see foxglove_server's docstring for why
    # a tick's messages may reach a client just before its time message).
    assert {k * DT_NS for k in range(1, ticks + 1)} <= set(client.times)
    assert client.times == sorted(client.times)

    # Running: the time advances by exactly dt per tick, as /clock does.
    before = len(client.times)
    pause(client, False)
    client.wait(lambda: len(client.times) >= before + 30, 20, "30 time messages while running")
    running = client.times[before:]
    assert set(np.diff(running)) == {DT_NS}
    probe.spin_until(lambda: stamp_of(deserialize_message(dds["/clock"].messages[-1], Clock)) >= running[-1], 20,
                     "/clock to catch up")
    clock = {stamp_of(deserialize_message(m, Clock)) for m in dds["/clock"].messages}
    assert len(set(running) & clock) >= 10


def test_client_publish_moves_a_body_and_is_recorded(live, tmp_path):
    """A wrench from a Foxglove client (CDR as the Publish panel sends it, and JSON) moves the body by the
    closed form, goes into the bag like a DDS command, and is echoed on the command topic's channel."""
    from cgp_sim_msgs.msg import ApplyWrench

    bag = tmp_path / "bag"
    node, client = live("--start-paused", "true", "--bag", str(bag))
    odom = client.subscribe("/cgp_sim/bodies/box/odom")
    echo = client.subscribe("/cgp_sim/bodies/box/wrench")

    # 12 N along world x at the COM for one tick: Δv = F dt / m ≈ 0.1 m/s.
    channel = client.advertise("/cgp_sim/bodies/box/wrench", "cdr", "geometry_msgs/msg/WrenchStamped")
    sent = wrench_stamped((12.0, 0.0, 0.0))
    client.publish(channel, sent)
    step(client)  # same socket, after the message: the command is taken before this step
    first = last_odom(client, odom, DT_NS)
    np.testing.assert_allclose(world_velocity(first), [12.0 / BOX_MASS * DT, 0.0, 0.0], rtol=1e-12, atol=1e-12)

    # JSON, the Publish panel's other encoding: ApplyWrench in the box's axes, ``point`` left out (its COM),
    # an integer where a float is expected.  The box has not turned: body z is world z.
    command = {"body": "box", "header": {"frame_id": "box"}, "wrench": {"force": {"z": 12}}}
    channel = client.advertise("/cgp_sim/apply_wrench", "json", "cgp_sim_msgs/ApplyWrench")
    client.publish(channel, json.dumps(command).encode())
    step(client)
    second = last_odom(client, odom, 2 * DT_NS)
    np.testing.assert_allclose(world_velocity(second), [6.0 * DT, 0.0, 6.0 * DT], rtol=1e-12, atol=1e-12)
    w = second.twist.twist.angular
    assert max(abs(w.x), abs(w.y), abs(w.z)) < 1e-9  # at the COM: no torque

    client.wait(lambda: client.messages[echo], 10, "the command echoed on its channel")
    assert [data for _, data in client.received(echo)] == [sent]
    assert node.stop() == 0
    recorded = bag_messages(bag)
    assert recorded["/cgp_sim/bodies/box/wrench"] == [sent]
    (apply,) = [deserialize_message(data, ApplyWrench) for data in recorded["/cgp_sim/apply_wrench"]]
    assert (apply.body, apply.header.frame_id, apply.wrench.force.z, apply.point.z) == ("box", "box", 12.0, 0.0)


def test_services_called_from_foxglove(live):
    """pause, step, clear_wrenches and reset do from Foxglove what they do over DDS (and are on ~/events)."""
    node, client = live()
    odom = client.subscribe("/cgp_sim/bodies/box/odom")
    audit = client.subscribe("/cgp_sim/events")
    pause(client, True)
    ticks = [int(re.search(r"tick (\d+)", step(client)).group(1)) for _ in range(2)]
    assert ticks[1] == ticks[0] + 1

    # A wrench until cleared (duration < 0): the box accelerates every step until ~/clear_wrenches.
    channel = client.advertise("/cgp_sim/apply_wrench", "cdr", "cgp_sim_msgs/msg/ApplyWrench")
    from cgp_sim_msgs.msg import ApplyWrench

    command = ApplyWrench(body="box")
    command.header.frame_id = "box"  # body axes, point at the COM
    command.wrench.force.y = 6.0
    command.duration.sec = -1
    client.publish(channel, serialize_message(command))
    speeds = []
    for _ in range(3):
        step(client)
        speeds.append(np.linalg.norm(world_velocity(last_odom(client, odom))))
    np.testing.assert_allclose(speeds, [3.0 * DT, 6.0 * DT, 9.0 * DT], rtol=1e-12)  # 6 N / 2 kg per tick
    cleared = deserialize_message(client.call("/cgp_sim/clear_wrenches", EMPTY_CDR_REQUEST), Trigger.Response)
    assert cleared.success and cleared.message == "cleared 1 active wrench(es) and 0 pending command(s)"
    step(client)
    assert np.linalg.norm(world_velocity(last_odom(client, odom))) == pytest.approx(speeds[-1], rel=1e-12)

    reset = deserialize_message(client.call("/cgp_sim/reset", serialize_message(Trigger.Request())),
                                Trigger.Response)
    assert reset.success, reset.message
    step(client)
    after = last_odom(client, odom)
    p = after.pose.pose.position
    assert (p.x, p.y, p.z) == (0.0, 0.0, 2.0) and np.linalg.norm(world_velocity(after)) == 0.0

    with pytest.raises(ServiceCallFailed, match="cannot decode"):  # a SetBool request of one byte
        client.call("/cgp_sim/pause", b"\x00")
    client.wait(lambda: [e.get("name") for e in events(client, audit)].count("reset") == 1, 10, "the audit trail")
    names = [e["name"] for e in events(client, audit) if e["event"] == "service"]
    assert names == ["pause", "step", "step", "step", "step", "step", "clear_wrenches", "step", "reset", "step"]
    assert node.alive()


def test_bad_client_input_is_rejected_and_the_node_keeps_ticking(live):
    """Refused channels, undecodable / oversized / non-finite messages, unknown channel ids and a flood from a
    WebSocket client are rejected through the node's reject path (each counted on ~/events), never reach the
    world, and the node keeps ticking; a valid command afterwards still works."""
    node, client = live()
    odom = client.subscribe("/cgp_sim/bodies/box/odom")
    audit = client.subscribe("/cgp_sim/events")
    client.wait(lambda: client.messages[odom], 20, "odometry")

    # Channels the node refuses when they are advertised (a status tells the app why).
    markers = client.advertise("/cgp_sim/markers", "cdr", "visualization_msgs/msg/MarkerArray")
    client.advertise("/cgp_sim/bodies/box/wrench", "protobuf", "geometry_msgs/msg/WrenchStamped")
    client.advertise("/cgp_sim/bodies/box/wrench", "cdr", "geometry_msgs/msg/Twist")
    client.wait(lambda: len([s for s in client.statuses if "refused channel" in s["message"]]) == 3, 20,
                "three refusal statuses")
    refusals = " ".join(s["message"] for s in client.statuses)
    assert "'/cgp_sim/markers' takes no commands" in refusals and "'protobuf'" in refusals
    assert "'geometry_msgs/msg/Twist' on /cgp_sim/bodies/box/wrench, which takes geometry_msgs/msg/WrenchStamped" \
        in refusals
    client.publish(markers, b"\x00\x01\x00\x00")
    client.publish(4242, b"\x00\x01\x00\x00")  # never advertised: the SDK answers, the node reports it
    client.ws.send('{"op": "bogus"}')

    box = client.advertise("/cgp_sim/bodies/box/wrench", "cdr", "geometry_msgs/msg/WrenchStamped")
    box_json = client.advertise("/cgp_sim/bodies/box/wrench", "json", "geometry_msgs/msg/WrenchStamped")
    client.publish(box, b"\x00\x01\x00\x00\xff\xff\xff")  # a truncated message
    client.publish(box, bytes(5000))  # larger than any WrenchStamped
    client.publish(box_json, b"{not json")
    client.publish(box_json, b'{"wrench": {"forse": {"x": 1}}}')
    client.publish(box_json, b'{"wrench": {"force": {"x": NaN}}}')  # Python's JSON has NaN; validation refuses

    def counted(source, field, kind):
        return sum(e["count"] for e in events(client, audit) if e["event"] == "rejected"
                   and (e["source"], e["field"], e["kind"]) == (source, field, kind))
    for report in [("foxglove", "topic", "unknown"), ("foxglove", "encoding", "unsupported"),
                   ("foxglove", "schemaName", "wrong type"), ("foxglove", "channel", "refused"),
                   ("foxglove", "client message", "invalid"), ("bodies/box/wrench", "message", "undecodable"),
                   ("foxglove", "message", "too large"), ("foxglove", "message", "undecodable"),
                   ("foxglove", "wrench.forse", "unknown field"), ("bodies/box/wrench", "wrench.force", "non-finite")]:
        client.wait(lambda: counted(*report) > 0, 20, f"a report of {report} on ~/events")
    # The SDK refuses the unknown channel id and the unknown op itself (error statuses to the client); its
    # records of them are counted with the rest (the first one logged at once, the summary names the last).
    client.wait(lambda: counted("foxglove", "client message", "invalid") == 2, 20, "both protocol errors counted")
    assert "rejected foxglove command: client message: Received message for unknown channel: 4242" in node.log()
    assert any(s["message"] == "Unknown channel ID: 4242" for s in client.statuses)

    # A flood of non-finite commands, as fast as the socket takes them: each one is rejected by the node's
    # validation or dropped (and counted) when too many wait; the node keeps ticking.
    def accounted():
        return counted("bodies/box/wrench", "wrench.force", "non-finite") + counted("foxglove", "message", "flood")
    client.wait(lambda: accounted() == 1, 20, "the NaN command's report")
    flood = wrench_stamped((math.inf, 0.0, 0.0))
    times_before = len(client.times)
    for _ in range(20_000):
        client.publish(box, flood)
    client.wait(lambda: accounted() == 1 + 20_000, 30, "every flooded command accounted for on ~/events")
    client.wait(lambda: len(client.times) >= times_before + 60, 30, "ticks going on after the flood")

    # Nothing reached the world; a valid command still does.
    for _, data in client.received(odom):
        assert np.linalg.norm(world_velocity(deserialize_message(data, Odometry))) == 0.0
    client.publish(box, wrench_stamped((12.0, 0.0, 0.0)))
    client.wait(lambda: np.linalg.norm(world_velocity(deserialize_message(client.messages[odom][-1][1], Odometry)))
                > 0, 20, "the valid command to move the box")
    np.testing.assert_allclose(world_velocity(deserialize_message(client.messages[odom][-1][1], Odometry)),
                               [6.0 * DT, 0.0, 0.0], rtol=1e-12, atol=1e-12)
    assert node.alive()
    assert "rejected foxglove command" in node.log()


def test_port_in_use_or_out_of_range_is_a_configuration_error(start_node, tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        node = start_node("--scene", "zero_g", "--foxglove", "true", "--foxglove-port", str(port),
                          "--bag", str(tmp_path / "bag"))
        assert node.wait(60) == 2
    log = node.log()
    assert f"foxglove: cannot listen on 127.0.0.1:{port}: Failed to bind port: Address already in use" in log
    assert not (tmp_path / "bag").exists()  # nothing started
    node = start_node("--scene", "zero_g", "--foxglove", "true", "--foxglove-port", "70000")
    assert node.wait(60) == 2
    assert "foxglove_port must be <= 65535, got 70000" in node.log()


def test_without_the_parameter_the_sdk_is_not_even_imported(tmp_path):
    code = textwrap.dedent("""
        import sys
        import rclpy
        from rclpy.parameter import Parameter
        from cgp_sim_ros.ros.node import SimNode

        rclpy.init()
        node = SimNode(parameter_overrides=[Parameter("scene", value="zero_g"), Parameter("realtime", value=False)])
        for _ in range(3):
            node.tick()
        assert node.foxglove is None
        print("loaded:", sorted(m for m in sys.modules if m.split(".")[0] in ("foxglove", "websockets")))
        node.destroy_node()
        rclpy.shutdown()
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "loaded: []" in out.stdout


def _panels(node) -> set[str]:
    """The panel ids of a layout tree (a panel id, or {first, second, ...})."""
    return {node} if isinstance(node, str) else _panels(node["first"]) | _panels(node["second"])


def test_the_layout_shows_what_the_default_scene_serves_and_its_kick_works(start_node):
    """msgs_config/foxglove/cgp_sim_layout.json names only channels and services the node offers (with their
    types), and the Publish panel's prefilled message, sent as the panel would, kicks the ball up."""
    from pathlib import Path

    layout = json.loads((Path(__file__).resolve().parents[1] / "msgs_config/foxglove/cgp_sim_layout.json")
                        .read_text())
    config = layout["configById"]
    assert _panels(layout["layout"]) == set(config)
    node = start_node("--foxglove", "true", "--foxglove-port", "0", "--start-paused", "true")  # default scene
    client = FoxgloveClient(foxglove_url(node))
    try:
        client.wait(lambda: len(client.services) == len(SERVICES) and client.channels, 20, "advertisements")
        client.channel("/cgp_sim/bodies/ball/wrench")
        channels = {c["topic"]: c for c in client.channels.values()}

        (three_d,) = [c for key, c in config.items() if key.startswith("3D!")]
        assert three_d["followTf"] == "world"
        assert set(three_d["topics"]) <= set(channels) and three_d["topics"]["/cgp_sim/markers"]["visible"]
        assert three_d["topics"]["/cgp_sim/static_markers"]["visible"]  # the static meshes (issue 38)
        plots = [c for key, c in config.items() if key.startswith("Plot!")]
        # the bodies' heights and the school's order parameters (issue 14: ~/flocks/<flock>/stats)
        assert {path["value"] for plot in plots for path in plot["paths"]} >= {
            "/cgp_sim/flocks/fish/stats.polarization", "/cgp_sim/flocks/fish/stats.milling"}
        message_types = {"nav_msgs/msg/Odometry": Odometry, "cgp_sim_msgs/msg/FlockStats": FlockStats}
        for path in [path for plot in plots for path in plot["paths"]]:
            topic, fields = path["value"].split(".", 1)
            value = message_types[channels[topic]["schemaName"]]()  # a channel the default scene serves
            for field in fields.split("."):
                value = getattr(value, field)  # the path names real fields
            assert isinstance(value, float)
        (call,) = [c for key, c in config.items() if key.startswith("CallService!")]
        assert call["serviceName"] in client.services
        (publish,) = [c for key, c in config.items() if key.startswith("Publish!")]
        assert channels[publish["topicName"]]["schemaName"] == publish["datatype"]

        # The panel's message, as JSON on the panel's topic and type: 900 N up for one tick on the 2 kg ball,
        # against gravity: v_z = (900 / 2 - 9.81) dt.
        odom = client.subscribe("/cgp_sim/bodies/ball/odom")
        panel = client.advertise(publish["topicName"], "json", publish["datatype"])
        client.publish(panel, publish["value"].encode())
        step(client)
        kicked = last_odom(client, odom, DT_NS)
        assert world_velocity(kicked)[2] == pytest.approx((900.0 / 2.0 - 9.81) * DT, rel=1e-12)
    finally:
        client.close()


def test_a_spawned_body_gets_its_channels_in_the_live_view(live, probe):
    """Issue 13 through the live view: a body spawned over ROS 2's simulation_interfaces is advertised as new
    channels (its odometry, its wrench command topic), its odometry flows at the tick's time, and a command a
    Foxglove client publishes on its wrench channel pushes it."""
    from sim_client import SimClient

    node, client = live("--start-paused", "true")
    sim = SimClient(probe)
    reply = sim.spawn("box1", "body: {shape: box, size: [0.4, 0.4, 0.4], mass: 2.0}", position=(0, -5, 2))
    assert reply.result.result == 1, reply.result
    odom = client.subscribe("/cgp_sim/bodies/box1/odom")  # waits for the channel's advertisement
    client.channel("/cgp_sim/bodies/box1/wrench")
    channel = client.advertise("/cgp_sim/bodies/box1/wrench", "cdr", "geometry_msgs/msg/WrenchStamped")
    push = WrenchStamped()
    push.wrench.force.y = 4.0
    client.publish(channel, serialize_message(push))
    for _ in range(3):
        step(client)  # same socket, after the message: the command is taken before the first step
    client.wait(lambda: len(client.messages[odom]) >= 3, 20, "box1's odometry over the WebSocket")
    stamp, data = client.received(odom)[-1]
    msg = deserialize_message(data, Odometry)
    assert msg.child_frame_id == "box1" and stamp_of(msg) == stamp
    assert world_velocity(msg)[1] == pytest.approx(4.0 * DT_NS * 1e-9 / 2.0, abs=1e-9)  # one tick of 4 N on 2 kg


def test_a_late_client_gets_the_latched_topics(live, probe):
    """Issue 38: the static meshes are sent once, on the latched ~/static_markers (and the fixed bodies on
    /tf_static): a Foxglove client that subscribes later gets their last message at once, as a DDS subscriber
    with transient-local durability does."""
    from sim_client import SimClient

    node, client = live("--start-paused", "true")
    sim = SimClient(probe)
    assert sim.spawn("land", "body: {shape: mesh, mesh: terrain.obj, fixed: true}").result.result == 1
    step(client)
    step(client)  # the first tick sent them; this one does not
    static = client.subscribe("/cgp_sim/static_markers")
    tf_static = client.subscribe("/tf_static")
    client.wait(lambda: client.messages[static] and client.messages[tf_static], 20, "the latched messages")
    (_, data), = client.received(static)
    markers = deserialize_message(data, MarkerArray).markers
    assert [m.ns for m in markers[:2]] == ["", "bodies/land"] and len(markers[1].points) == 3 * 1152
    assert {m.ns for m in markers[2:]} == {"bodies/box", "bodies/spinner"}  # the scene's bodies (issue 37)

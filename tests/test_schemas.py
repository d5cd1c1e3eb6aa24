"""cgp_sim_ros.wire.schemas: rosbag2's schema text, type hashes and QoS YAML, checked against independent sources.

- The concatenated definition is rebuilt here from the rosidl type descriptions (``<Type>.json``: the fields'
  nested types, not the regular expression over the ``.msg`` text that rosbag2 and the module use) and the raw
  ``.msg`` files, with rosbag2's documented order (sorted dependencies, depth first, each type once).
- rosbags parses the text and computes the RIHS01 hash itself; it must equal the installed hash.
- The QoS YAML is compared with the rmw names of the policies and with what the live ROS graph reports for a
  publisher (rosbag2 records the offered QoS it discovers).
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import pytest
import yaml
from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from cgp_sim_ros.wire import schemas

TYPES = (
    "geometry_msgs/msg/PoseArray",
    "visualization_msgs/msg/Marker",
    "visualization_msgs/msg/MarkerArray",
    "nav_msgs/msg/Odometry",
    "rosgraph_msgs/msg/Clock",
    "geometry_msgs/msg/WrenchStamped",
    "cgp_sim_msgs/msg/ApplyWrench",
    "std_msgs/msg/Header",
    "builtin_interfaces/msg/Time",
    "sensor_msgs/msg/CompressedImage",
)
SHARE = Path(sys.prefix, "share")
INFINITE = {"sec": 9223372036, "nsec": 854775807}


def _short(name: str) -> str:
    """'pkg/msg/Type' -> 'pkg/Type' (how .msg files and the MSG: lines name types)."""
    package, _, type_name = name.split("/")
    return f"{package}/{type_name}"


def _description_dependencies() -> dict[str, list[str]]:
    """Every type's direct dependencies, from the installed type-description JSON files."""
    deps: dict[str, list[str]] = {}
    for json_path in SHARE.glob("*/msg/*.json"):
        doc = json.loads(json_path.read_text())["type_description_msg"]
        for desc in [doc["type_description"], *doc["referenced_type_descriptions"]]:
            nested = {f["type"]["nested_type_name"] for f in desc["fields"]} - {""}
            deps[_short(desc["type_name"])] = sorted(_short(n) for n in nested)
    return deps


DEPENDENCIES = _description_dependencies()


def rebuild_definition(type_name: str) -> str:
    """Second implementation: JSON dependencies + raw files, rosbag2's order."""
    seen: set[str] = set()

    def text(short: str) -> str:
        package, name = short.split("/")
        return (SHARE / package / "msg" / f"{name}.msg").read_bytes().decode("utf-8")

    def walk(short: str) -> str:
        out = text(short)
        for dep in DEPENDENCIES[short]:  # sorted
            if dep not in seen:
                seen.add(dep)
                out += "\n" + "=" * 80 + "\nMSG: " + dep + "\n" + walk(dep)
        return out

    return walk(_short(type_name))


@pytest.mark.parametrize("type_name", TYPES)
def test_definition_equals_independent_rebuild(type_name):
    assert schemas.message_definition(type_name) == rebuild_definition(type_name)


@pytest.mark.parametrize("type_name", TYPES)
def test_definition_parses_to_the_installed_type_hash(type_name):
    """rosbags parses the text and hashes the types it finds: the hash must be the one rosidl installed."""
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(schemas.message_definition(type_name), type_name))
    package, _, name = type_name.split("/")
    installed = json.loads((SHARE / package / "msg" / f"{name}.json").read_text())["type_hashes"][0]
    assert installed["type_name"] == type_name
    assert store.hash_rihs01(type_name) == installed["hash_string"] == schemas.type_hash(type_name)


def test_definition_layout_root_first_each_dependency_once():
    text = schemas.message_definition("visualization_msgs/msg/MarkerArray")
    sections = text.split("\n" + "=" * 80 + "\n")
    assert sections[0] == (SHARE / "visualization_msgs/msg/MarkerArray.msg").read_text()
    names = [s.split("\n", 1)[0] for s in sections[1:]]
    assert all(n.startswith("MSG: ") for n in names)
    assert len(names) == len(set(names))
    # Every type reachable from MarkerArray, and nothing else.
    reachable, todo = set(), ["visualization_msgs/MarkerArray"]
    while todo:
        for dep in DEPENDENCIES[todo.pop()]:
            if dep not in reachable:
                reachable.add(dep)
                todo.append(dep)
    assert {n[len("MSG: "):] for n in names} == reachable


def test_pkg_type_names_are_accepted():
    assert schemas.message_definition("geometry_msgs/PoseArray") == schemas.message_definition(
        "geometry_msgs/msg/PoseArray")
    assert schemas.type_hash("geometry_msgs/PoseArray") == schemas.type_hash("geometry_msgs/msg/PoseArray")


def test_dependency_scan_follows_rosbag2_rules():
    text = ("# Baz is mentioned in a comment only\n"
            "Header header  # a bare name: same package\n"
            "foo_msgs/Bar[] bars\n"
            "foo_msgs/Bar[<=3] more_bars\n"
            "uint8[<=3] small\n"
            "  string indented\n"
            "\n"
            "Bounded[4] fixed\n"
            "int32 CONSTANT=3\n"
            "string<=5 short_string\n")
    assert schemas.message_dependencies(text, "pkg") == ["foo_msgs/Bar", "pkg/Bounded", "pkg/Header"]


@pytest.mark.parametrize("bad, error, match", [
    ("geometry_msgs/msg/NoSuchType", FileNotFoundError, "NoSuchType.msg"),
    ("no_such_pkg/msg/X", FileNotFoundError, "no_such_pkg"),
    ("PoseArray", ValueError, "not a ROS interface type name"),
    ("a/b/c/d", ValueError, "not a ROS interface type name"),
])
def test_bad_type_names_give_clear_errors(bad, error, match):
    with pytest.raises(error, match=match):
        schemas.message_definition(bad)


@pytest.fixture
def fresh_caches():
    for cached in (schemas.share_directory, schemas.message_definition, schemas.type_hash,
                   schemas._msg_text):
        cached.cache_clear()
    yield
    for cached in (schemas.share_directory, schemas.message_definition, schemas.type_hash,
                   schemas._msg_text):
        cached.cache_clear()


def test_share_directories_come_from_ament_prefix_path_first(tmp_path, monkeypatch, fresh_caches):
    """A package on AMENT_PREFIX_PATH is found through ament_index_python; the venv's are still found."""
    prefix = tmp_path / "prefix"
    (prefix / "share/ament_index/resource_index/packages").mkdir(parents=True)
    (prefix / "share/ament_index/resource_index/packages/fake_msgs").write_text("")
    (prefix / "share/fake_msgs/msg").mkdir(parents=True)
    (prefix / "share/fake_msgs/msg/Thing.msg").write_text("std_msgs/Header header\nInner inner\n")
    (prefix / "share/fake_msgs/msg/Inner.msg").write_text("float64 x\n")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    assert schemas.share_directory("fake_msgs") == prefix / "share/fake_msgs"
    text = schemas.message_definition("fake_msgs/msg/Thing")
    sep = "\n" + "=" * 80 + "\n"
    assert text == ("std_msgs/Header header\nInner inner\n" + sep + "MSG: fake_msgs/Inner\nfloat64 x\n" + sep
                    + "MSG: std_msgs/Header\n" + rebuild_definition("std_msgs/msg/Header"))


# ------------------------------------------------------------------------------------------------- QoS
def test_qos_yaml_of_the_default_profile_as_rosbag2_writes_it():
    expected = "\n".join([
        "- history: keep_last",
        "  depth: 10",
        "  reliability: reliable",
        "  durability: volatile",
        "  deadline:",
        "    sec: 0",
        "    nsec: 0",
        "  lifespan:",
        "    sec: 0",
        "    nsec: 0",
        "  liveliness: system_default",
        "  liveliness_lease_duration:",
        "    sec: 0",
        "    nsec: 0",
        "  avoid_ros_namespace_conventions: false",
    ])
    assert schemas.offered_qos_profiles_yaml(QoSProfile(depth=10), as_discovered=False) == expected
    assert schemas.offered_qos_profiles_yaml([]) == "[]"


CUSTOM = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.BEST_EFFORT,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL, deadline=Duration(seconds=1, nanoseconds=5),
                    lifespan=Duration(seconds=2), liveliness=LivelinessPolicy.MANUAL_BY_TOPIC,
                    liveliness_lease_duration=Duration(nanoseconds=300), avoid_ros_namespace_conventions=True)


def test_qos_profile_as_given_uses_rmw_names():
    assert yaml.safe_load(schemas.offered_qos_profiles_yaml(CUSTOM, as_discovered=False)) == [{
        "history": "keep_all", "depth": CUSTOM.depth, "reliability": "best_effort",
        "durability": "transient_local", "deadline": {"sec": 1, "nsec": 5}, "lifespan": {"sec": 2, "nsec": 0},
        "liveliness": "manual_by_topic", "liveliness_lease_duration": {"sec": 0, "nsec": 300},
        "avoid_ros_namespace_conventions": True}]


def test_qos_yaml_reads_back_in_rosbags():
    text = schemas.offered_qos_profiles_yaml([QoSProfile(depth=10), CUSTOM], as_discovered=True)
    assert parse_qos(text) == [
        Qos(QosHistory.UNKNOWN, 0, QosReliability.RELIABLE, QosDurability.VOLATILE, QosTime(**INFINITE),
            QosTime(**INFINITE), QosLiveliness.AUTOMATIC, QosTime(**INFINITE), False),
        Qos(QosHistory.UNKNOWN, 0, QosReliability.BEST_EFFORT, QosDurability.TRANSIENT_LOCAL, QosTime(1, 5),
            QosTime(2, 0), QosLiveliness.MANUAL_BY_TOPIC, QosTime(0, 300), True),
    ]


def test_as_discovered_equals_what_the_ros_graph_reports():
    """rosbag2 stores the QoS it discovers for each publisher: publish with a profile, ask the graph."""
    import rclpy
    from rclpy.context import Context
    from std_msgs.msg import Header

    context = Context()
    rclpy.init(context=context, domain_id=(os.getpid() % 100) + 101)
    try:
        node = rclpy.create_node("qos_probe", context=context)
        # (avoid_ros_namespace_conventions=True would publish outside the ROS name space, out of this query)
        graph_custom = QoSProfile(history=CUSTOM.history, depth=CUSTOM.depth, reliability=CUSTOM.reliability,
                                  durability=CUSTOM.durability, deadline=CUSTOM.deadline,
                                  lifespan=CUSTOM.lifespan, liveliness=CUSTOM.liveliness,
                                  liveliness_lease_duration=CUSTOM.liveliness_lease_duration)
        profiles = {"default_qos": QoSProfile(depth=10), "sensor_qos": qos_profile_sensor_data,
                    "custom_qos": graph_custom}
        publishers = [node.create_publisher(Header, name, p) for name, p in profiles.items()]
        for name, profile in profiles.items():
            deadline = time.monotonic() + 10.0
            while not (infos := node.get_publishers_info_by_topic(name)) and time.monotonic() < deadline:
                time.sleep(0.01)
            assert len(infos) == 1, f"publisher on {name} not in the graph"
            assert schemas.qos_profile_dict(infos[0].qos_profile, as_discovered=False) == \
                schemas.qos_profile_dict(profile, as_discovered=True), name
        del publishers
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


# ------------------------------------------------------------------------------------------ YAML emit
@pytest.mark.parametrize("value", [
    {"a": "", "b": "yes", "c": "123", "d": "1e3", "e": "a: b", "f": "wörld", "g": "~", "h": " x",
     "i": "-", "j": "/cgp_sim/bodies/ball_1/odom", "k": "null", "l": "#x", "m": 'q"uote\\'},
    {"nested": {"list": [{"x": 1, "y": [1, 2]}, {"z": None}], "empty_list": [], "empty_map": {}}},
    [{"history": "keep_last", "depth": 1}],
])
def test_dump_yaml_round_trips(value):
    loaded = yaml.safe_load(schemas.dump_yaml(value))
    if isinstance(value, dict) and "nested" in value:
        value = {"nested": {**value["nested"], "empty_map": None}}  # yaml-cpp writes an empty map as ~
    assert loaded == value


# ---------------------------------------------------------------------------------------------- services
SERVICES = ("std_srvs/srv/Trigger", "std_srvs/srv/SetBool", "rcl_interfaces/srv/SetParameters")


@pytest.mark.parametrize("srv", SERVICES)
def test_service_definitions_are_the_srv_halves_with_their_dependencies(srv):
    """What the Foxglove server advertises for a service: each half of the .srv file, then the types it uses in
    rosbag2's order — rebuilt here from the service's installed type description (its Request / Response
    fields' nested types), and parsed by rosbags to the fields rclpy's generated classes have."""
    import importlib

    request, response = schemas.service_definitions(srv)
    package, _, name = srv.split("/")
    srv_file = (SHARE / package / "srv" / f"{name}.srv").read_text()
    sep = "\n" + "=" * 80 + "\n"
    request_root, response_root = request.split(sep)[0], response.split(sep)[0]
    assert request_root + "---\n" + response_root == srv_file

    description = json.loads((SHARE / package / "srv" / f"{name}.json").read_text())["type_description_msg"]
    by_name = {d["type_name"]: d for d in description["referenced_type_descriptions"]}
    srv_class = getattr(importlib.import_module(f"{package}.srv"), name)

    def msg_text(short: str) -> str:
        package, name = short.split("/")
        return (SHARE / package / "msg" / f"{name}.msg").read_bytes().decode("utf-8")

    for part, text, root in (("Request", request, request_root), ("Response", response, response_root)):
        fields = by_name[f"{srv}_{part}"]["fields"]
        nested = sorted({_short(f["type"]["nested_type_name"]) for f in fields if f["type"]["nested_type_name"]})
        seen: set[str] = set()

        def walk(deps) -> str:
            out = ""
            for dep in deps:  # sorted, depth first, each type once
                if dep not in seen:
                    seen.add(dep)
                    out += sep + "MSG: " + dep + "\n" + msg_text(dep) + walk(DEPENDENCIES[dep])
            return out

        assert text == root + walk(nested), part
        msg_name = f"{package}/msg/{name}_{part}"  # rosbags parses messages
        parsed = get_types_from_msg(text, msg_name)[msg_name]
        assert [f[0] for f in parsed[1]] == list(getattr(srv_class, part).get_fields_and_field_types()), part


def test_service_definitions_refuse_a_message_type():
    with pytest.raises(ValueError, match="not a service type"):
        schemas.service_definitions("std_msgs/msg/String")

"""What rosbag2 (Jazzy) stores about a message type and a topic, built the way rosbag2 builds it.

- :func:`message_definition`: the ``ros2msg`` schema text of an MCAP schema record.  rosbag2's
  ``LocalMessageDefinitionSource::get_full_text`` (rosbag2_cpp) does, and so does this module:
  1. read the root type's ``.msg`` file verbatim from ``<share dir of its package>/msg/<Type>.msg``
     (comments, blank lines and the trailing newline kept);
  2. find its dependencies with the regular expression ``(?:^|\\n)\\s*([a-zA-Z0-9_/]+)(?:\\[[^\\]]*\\])?\\s+``
     over the whole text (the type token at the start of each line), drop the primitive types, and qualify
     a bare ``Type`` with the package of the file being parsed (``UVCoordinate`` in a visualization_msgs file
     means ``visualization_msgs/UVCoordinate``);
  3. visit the dependencies in sorted (``std::set``) order, depth first; each type not yet emitted anywhere in
     the text is appended as ``"\\n" + "=" * 80 + "\\n" + "MSG: " + name + "\\n" + its file text`` followed
     by its own dependencies, recursively.  ``name`` is written as in the referring file (``pkg/Type``).
- :func:`type_hash`: the ``RIHS01_…`` type description hash, read from the ``<Type>.json`` type description
  that rosidl installs next to the ``.msg`` (what rosbag2 stores as ``type_description_hash`` /
  ``topic_type_hash``).
- :func:`offered_qos_profiles_yaml`: the ``offered_qos_profiles`` value of an MCAP channel, i.e.
  ``rosbag2_storage::serialize_rclcpp_qos_vector`` = yaml-cpp ``YAML::Dump`` of a sequence of QoS maps with
  the metadata-version-9 encoding (policies as lower-case strings, durations as ``{sec, nsec}``).
- :func:`dump_yaml`: a yaml-cpp-style block emitter, shared with ``bag.py`` for ``metadata.yaml`` and the
  ``rosbag2`` metadata record.

Share directories come from ``ament_index_python`` (``AMENT_PREFIX_PATH``, as on a sourced ROS install); when
that is unset or does not know the package, the ament index of this interpreter's prefix is used (the PyPI
``ros-*`` wheels install ``share/`` into the venv without setting ``AMENT_PREFIX_PATH``).
"""

from __future__ import annotations

import functools
import json
import math
import os
import re
import sys
from collections.abc import Iterable
from pathlib import Path

__all__ = [
    "normalize_type_name",
    "share_directory",
    "message_definition",
    "message_dependencies",
    "service_definitions",
    "type_hash",
    "qos_profile_dict",
    "offered_qos_profiles_yaml",
    "dump_yaml",
    "SEPARATOR",
]

#: The line between concatenated definitions (80 '=').
SEPARATOR = "=" * 80

# Same expression as rosbag2's MSG_FIELD_TYPE_REGEX; re.ASCII makes \s match what std::regex's \s matches.
_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+", re.ASCII)
_PRIMITIVE_TYPES = frozenset((
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32",
    "int64", "uint64", "string"))
_NAME = r"[a-zA-Z][a-zA-Z0-9_]*"
_TYPE_NAME = re.compile(rf"^({_NAME})/(?:({_NAME})/)?({_NAME})$")
_MAX_DEPTH = 50  # rosbag2's ROSBAG2_CPP_LOCAL_MESSAGE_DEFINITION_SOURCE_MAX_RECURSION_DEPTH


def normalize_type_name(type_name: str) -> tuple[str, str, str]:
    """``(package, interface kind, Type)`` of ``pkg/Type`` or ``pkg/msg/Type``."""
    match = _TYPE_NAME.match(type_name)
    if not match:
        raise ValueError(f"{type_name!r} is not a ROS interface type name (expected 'pkg/msg/Type' or "
                         f"'pkg/Type')")
    package, kind, name = match.groups()
    return package, kind or "msg", name


@functools.cache
def share_directory(package: str) -> Path:
    """``<prefix>/share/<package>`` of an installed ROS package (see the module docstring for the search)."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:  # pragma: no cover - ament_index_python ships with the rclpy wheels
        pass
    else:
        try:
            return Path(get_package_share_directory(package))
        except (PackageNotFoundError, OSError, ValueError):
            pass
    marker = Path(sys.prefix, "share", "ament_index", "resource_index", "packages", package)
    if marker.is_file():
        return Path(sys.prefix, "share", package)
    searched = os.environ.get("AMENT_PREFIX_PATH") or "(AMENT_PREFIX_PATH unset)"
    raise FileNotFoundError(f"ROS package {package!r} is not installed: not in the ament index of "
                            f"{searched} nor of {sys.prefix}")


def _interface_file(type_name: str, suffix: str) -> Path:
    package, kind, name = normalize_type_name(type_name)
    path = share_directory(package) / kind / f"{name}{suffix}"
    if not path.is_file():
        raise FileNotFoundError(f"no {suffix} file for {type_name!r}: {path} does not exist")
    return path


@functools.cache
def _msg_text(type_name: str) -> str:
    # newline="" keeps the file's bytes as they are (rosbag2 reads the file in binary-equivalent mode).
    with open(_interface_file(type_name, ".msg"), encoding="utf-8", newline="") as f:
        return f.read()


def message_dependencies(text: str, package: str) -> list[str]:
    """Direct dependencies of a ``.msg`` text, as rosbag2 finds them: sorted, unique, ``pkg/Type``."""
    found = set()
    for match in _FIELD_TYPE.finditer(text):
        name = match.group(1)
        if name in _PRIMITIVE_TYPES:
            continue
        found.add(name if "/" in name else f"{package}/{name}")
    return sorted(found)


def _with_dependencies(text: str, package: str, what: str) -> str:
    """``text`` (a ``.msg`` text of ``package``) followed by its dependencies, rosbag2's way (module docstring)."""
    emitted: set[str] = set()

    def append(text: str, package: str, depth: int) -> str:
        if depth <= 0:
            raise RecursionError(f"reached the maximum depth resolving the definition of {what}")
        parts = [text]
        for dependency in message_dependencies(text, package):
            if dependency not in emitted:
                emitted.add(dependency)
                parts.append(f"\n{SEPARATOR}\nMSG: {dependency}\n")
                parts.append(append(_msg_text(dependency), normalize_type_name(dependency)[0], depth - 1))
        return "".join(parts)

    return append(text, package, _MAX_DEPTH)


@functools.cache
def message_definition(type_name: str) -> str:
    """The ``ros2msg`` concatenated definition of ``type_name`` (rosbag2's schema data)."""
    return _with_dependencies(_msg_text(type_name), normalize_type_name(type_name)[0], type_name)


_SRV_SEPARATOR = re.compile(r"^---[ \t]*(?:\r?\n|$)", re.MULTILINE)


@functools.cache
def service_definitions(type_name: str) -> tuple[str, str]:
    """The ``ros2msg`` concatenated definitions of a service's request and response (``pkg/srv/Type``).

    The ``.srv`` file is split at its ``---`` line and each part gets its dependencies appended as in
    :func:`message_definition` — what foxglove_bridge advertises as the ``pkg/srv/Type_Request`` and
    ``_Response`` schemas (rosbag2 records no services, so there is no rosbag2 form to follow)."""
    package, kind, name = normalize_type_name(type_name)
    if kind != "srv":
        raise ValueError(f"{type_name!r} is not a service type (expected 'pkg/srv/Type')")
    with open(_interface_file(type_name, ".srv"), encoding="utf-8", newline="") as f:
        text = f.read()
    parts = _SRV_SEPARATOR.split(text, maxsplit=1)
    if len(parts) != 2:
        raise ValueError(f"{type_name}: its .srv file has no '---' line between request and response")
    request, response = parts
    return (_with_dependencies(request, package, f"{type_name}_Request"),
            _with_dependencies(response, package, f"{type_name}_Response"))


@functools.cache
def type_hash(type_name: str) -> str:
    """``RIHS01_<sha256>`` of the type, from its installed type description (``<Type>.json``)."""
    package, kind, name = normalize_type_name(type_name)
    full = f"{package}/{kind}/{name}"
    with open(_interface_file(type_name, ".json"), encoding="utf-8") as f:
        description = json.load(f)
    for entry in description.get("type_hashes", ()):
        if entry.get("type_name") == full:
            return entry["hash_string"]
    raise ValueError(f"{full}: its type description file has no hash for {full}")


# -------------------------------------------------------------------------------------------------- QoS
_RMW_DURATION_INFINITE = (9223372036, 854775807)  # RMW_DURATION_INFINITE = INT64_MAX ns as {sec, nsec}


def _duration(value, as_discovered: bool) -> dict:
    """``{sec, nsec}`` of an rclpy Duration.  0 (the rmw "default", i.e. unlimited) is written as
    RMW_DURATION_INFINITE when ``as_discovered``, as the graph reports it."""
    ns = int(getattr(value, "nanoseconds", value))
    if ns >= 2**63 - 1 or (ns == 0 and as_discovered):
        sec, nsec = _RMW_DURATION_INFINITE
    else:
        sec, nsec = divmod(ns, 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def _policy_name(policy) -> str:
    # rclpy policies are IntEnums named like rmw's constants; rmw_qos_*_policy_to_str gives the lower case
    # (keep_last, best_effort, transient_local, manual_by_topic, system_default, best_available, unknown).
    return policy.name.lower()


def qos_profile_dict(profile, as_discovered: bool = True) -> dict:
    """One QoS profile as rosbag2's metadata version 9 encodes it (``convert<Rosbag2QoS>::encode``).

    ``as_discovered=True`` writes what rosbag2 would store when recording the publisher from the ROS graph
    (``get_publishers_info_by_topic`` with Fast DDS, checked on this machine): history ``unknown`` with depth
    0 (DDS discovery does not carry them), the system-default policies resolved to Fast DDS's defaults
    (reliable, volatile, automatic) and unset durations as infinite.  ``False`` writes the profile as given.
    """
    history, depth = _policy_name(profile.history), int(profile.depth)
    reliability = _policy_name(profile.reliability)
    durability = _policy_name(profile.durability)
    liveliness = _policy_name(profile.liveliness)
    if as_discovered:
        history, depth = "unknown", 0
        reliability = "reliable" if reliability == "system_default" else reliability
        durability = "volatile" if durability == "system_default" else durability
        liveliness = "automatic" if liveliness == "system_default" else liveliness
    return {
        "history": history,
        "depth": depth,
        "reliability": reliability,
        "durability": durability,
        "deadline": _duration(profile.deadline, as_discovered),
        "lifespan": _duration(profile.lifespan, as_discovered),
        "liveliness": liveliness,
        "liveliness_lease_duration": _duration(profile.liveliness_lease_duration, as_discovered),
        "avoid_ros_namespace_conventions": bool(profile.avoid_ros_namespace_conventions),
    }


def offered_qos_profiles_yaml(profiles, as_discovered: bool = True) -> str:
    """The ``offered_qos_profiles`` MCAP channel metadata value for one profile or a list of profiles
    (YAML::Dump output: block style, no trailing newline; ``[]`` when empty)."""
    if not isinstance(profiles, Iterable):
        profiles = [profiles]
    return dump_yaml([qos_profile_dict(p, as_discovered) for p in profiles])


# -------------------------------------------------------------------------------------------- YAML emit
_PLAIN = re.compile(r"^[A-Za-z0-9_/.][A-Za-z0-9_/.\-]*$")
_YAML_SPECIAL = re.compile(
    r"^(?:~|null|Null|NULL|true|True|TRUE|false|False|FALSE|yes|Yes|YES|no|No|NO|on|On|ON|off|Off|OFF|y|Y|n|N"
    r"|[-+]?(?:[0-9][0-9_]*)?(?:\.[0-9_]*)?(?:[eE][-+]?[0-9]+)?|0x[0-9a-fA-F_]+|0o[0-7_]+|\.inf|\.nan)$")


def _scalar(value) -> str:
    if value is None:
        return "~"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else (".nan" if math.isnan(value) else
                                                        (".inf" if value > 0 else "-.inf"))
    text = str(value)
    if text and _PLAIN.match(text) and not _YAML_SPECIAL.match(text):
        return text
    return json.dumps(text, ensure_ascii=False)  # a JSON string is a valid YAML double-quoted scalar


def _is_block(value) -> bool:
    return isinstance(value, (dict, list, tuple)) and len(value) > 0


def _emit(value, indent: int, lines: list[str]) -> None:
    """Block-style lines of a non-empty dict/list at ``indent`` spaces (yaml-cpp's layout: two spaces per
    level, sequences under a key indented by two, ``- `` followed by the first key of a mapping item)."""
    pad = " " * indent
    if isinstance(value, dict):
        for key, item in value.items():
            if _is_block(item):
                lines.append(f"{pad}{_scalar(key)}:")
                _emit(item, indent + 2, lines)
            else:
                lines.append(f"{pad}{_scalar(key)}: {_flow_empty(item)}")
    else:
        for item in value:
            if _is_block(item):
                inner: list[str] = []
                _emit(item, indent + 2, inner)
                lines.append(f"{pad}- {inner[0][indent + 2:]}")
                lines.extend(inner[1:])
            else:
                lines.append(f"{pad}- {_flow_empty(item)}")


def _flow_empty(value) -> str:
    if isinstance(value, dict):
        return "~"
    if isinstance(value, (list, tuple)):
        return "[]"
    return _scalar(value)


def dump_yaml(value) -> str:
    """yaml-cpp ``YAML::Dump``-style block YAML of dicts / lists / scalars, without a trailing newline.

    Empty dicts and ``None`` are written ``~`` (yaml-cpp's null: an empty map node is undefined, as in
    ``custom_data: ~``), empty lists ``[]``.
    """
    if not _is_block(value):
        return _flow_empty(value)
    lines: list[str] = []
    _emit(value, 0, lines)
    return "\n".join(lines)

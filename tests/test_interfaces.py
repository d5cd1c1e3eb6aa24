"""The interface packages the node speaks are ROS 2 Jazzy's own, field for field.

``msgs_config/upstream/`` carries copies of ``simulation_interfaces`` 1.5.1 and ``tf2_msgs`` (Jazzy), built into
the venv when the environment has no such package (``tools/build_msgs.py``).  The reference,
``tests/data/jazzy_interfaces.json``, was written from the upstream repositories by
``tools/make_interface_reference.py``: each file's git blob id and the RIHS01 hash of every type, computed by
rosbags (independent of rosidl) from the upstream text.  Nothing here needs the network.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import os
import re
import sys
from pathlib import Path

import pytest

from cgp_sim_ros.wire import schemas

REPO = Path(__file__).resolve().parents[1]
REFERENCE = json.loads((REPO / "tests" / "data" / "jazzy_interfaces.json").read_text(encoding="utf-8"))
PACKAGES = sorted(REFERENCE["packages"])
sys.path.insert(0, str(REPO / "tools"))
import build_msgs  # noqa: E402  (the set-up script, imported for its package lookup)


def _git_blob_id(data: bytes) -> str:
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


@pytest.mark.parametrize("package", PACKAGES)
def test_our_copies_are_byte_identical_to_upstream(package):
    ref = REFERENCE["packages"][package]
    root = REPO / "msgs_config" / "upstream" / package
    ours = {str(p.relative_to(root)): _git_blob_id(p.read_bytes())
            for kind in ("msg", "srv", "action") for p in sorted((root / kind).glob("*")) if p.is_file()}
    assert sorted(ours) == sorted(ref["files"]), "the set of interface files differs from upstream"
    different = [name for name in ours if ours[name] != ref["files"][name]]
    assert not different, f"not identical to {ref['repository']} at {ref['commit']}: {different}"


@pytest.mark.parametrize("package", PACKAGES)
def test_the_installed_package_has_the_jazzy_type_hashes(package):
    """What real clients check when they match: the type hash of each type, as the installed package (ours
    built by rosidl, or a real Jazzy install's) records it in its type descriptions."""
    share = schemas.share_directory(package)
    installed = {}
    for path in share.glob("*/*.json"):
        for entry in json.loads(path.read_text(encoding="utf-8")).get("type_hashes", ()):
            installed[entry["type_name"]] = entry["hash_string"]
    expected = REFERENCE["packages"][package]["type_hashes"]
    assert len(expected) > 3
    wrong = {name: (installed.get(name), want) for name, want in expected.items() if installed.get(name) != want}
    assert not wrong, f"{package} in {share}: type hashes differ from Jazzy's (installed, Jazzy): {wrong}"


# `uint8 NAME = 3` / `string NAME="text"` constant lines of a .msg text (comments after # removed)
_CONSTANT = re.compile(r"^\s*([a-z0-9_]+)\s+([A-Z][A-Z0-9_]*)\s*=\s*(.+?)\s*$")


def _constants(text: str) -> dict[str, object]:
    found = {}
    for line in text.splitlines():
        match = _CONSTANT.match(line.split("#", 1)[0])
        if match:
            kind, name, value = match.groups()
            found[name] = value.strip("\"'") if kind == "string" else (float(value) if "float" in kind
                                                                          else int(value))
    return found


@pytest.mark.parametrize("package", PACKAGES)
def test_the_python_classes_have_the_jazzy_constants(package):
    """Constants are not part of the type hash: check them in the generated Python classes against the
    (byte-identical, see above) definitions."""
    root = REPO / "msgs_config" / "upstream" / package
    checked = 0
    for path in sorted(root.glob("*/*.*")):
        kind = path.parent.name
        if kind not in ("msg", "srv", "action"):
            continue
        module = importlib.import_module(f"{package}.{kind}")
        parts = re.split(r"^---\s*$", path.read_text(encoding="utf-8"), flags=re.M)
        suffixes = {"msg": [""], "srv": [".Request", ".Response"], "action": [".Goal", ".Result", ".Feedback"]}
        for suffix, text in zip(suffixes[kind], parts):
            cls = getattr(module, path.stem)
            for attribute in filter(None, suffix.split(".")):
                cls = getattr(cls, attribute)
            for name, value in _constants(text).items():
                assert getattr(cls, name) == value, f"{package}/{kind}/{path.stem}{suffix}.{name}"
                checked += 1
    assert checked >= 7, checked


def test_build_msgs_uses_an_installed_package_instead_of_our_copy(tmp_path):
    """On a real ROS install (the package in the ament index of a prefix on AMENT_PREFIX_PATH) our copy is not
    built; a copy this script built (its marker file) is ours and is rebuilt when its sources change."""
    venv, ros = tmp_path / "venv", tmp_path / "opt_ros_jazzy"

    def install(prefix: Path, package: str, ours: bool) -> None:
        index = prefix / "share" / "ament_index" / "resource_index" / "packages"
        index.mkdir(parents=True, exist_ok=True)
        (index / package).write_text("")
        (prefix / "share" / package).mkdir(parents=True, exist_ok=True)
        if ours:
            (prefix / "share" / package / build_msgs.MARKER).write_text("ours")

    assert build_msgs.installed_elsewhere("tf2_msgs", venv, {}) is None  # nowhere: build ours
    install(venv, "tf2_msgs", ours=True)
    assert build_msgs.installed_elsewhere("tf2_msgs", venv, {}) is None  # only our own copy: rebuild it
    install(ros, "tf2_msgs", ours=False)
    assert build_msgs.installed_elsewhere("tf2_msgs", venv, {"AMENT_PREFIX_PATH": str(ros)}) == ros
    install(venv, "simulation_interfaces", ours=False)  # e.g. a future wheel, installed into the venv
    assert build_msgs.installed_elsewhere("simulation_interfaces", venv, {}) == venv


def test_build_msgs_rebuilds_a_package_only_when_its_inputs_change(tmp_path, monkeypatch):
    """The stamp of a package is a hash of its sources (and of the build script): another package's edit, or
    a checkout that only touched the files' times, leaves it alone; an edit of its own sources does not."""
    source = tmp_path / "pkg"
    (source / "msg").mkdir(parents=True)
    (source / "msg" / "A.msg").write_text("float64 x\n")
    (source / "CMakeLists.txt").write_text("project(pkg)\n")
    first = build_msgs.build_inputs_hash("pkg", source)
    os.utime(source / "msg" / "A.msg", (1, 1))  # a new time only
    assert build_msgs.build_inputs_hash("pkg", source) == first
    assert build_msgs.build_inputs_hash("other", source) != first
    (source / "msg" / "A.msg").write_text("float64 x\nfloat64 y\n")
    assert build_msgs.build_inputs_hash("pkg", source) != first


def test_frame_prefix_names_the_frames_and_is_checked():
    from cgp_sim_ros import interface as itf
    from cgp_sim_ros.ros.parameters import check_parameter

    frames = itf.Frames("sim2/")
    assert (frames.world, frames.body("ball")) == ("sim2/world", "sim2/ball")
    # what the node is sent: with or without the prefix, as cgp_core names the frames
    assert [frames.to_core(f) for f in ("", "world", "sim2/world", "ball", "sim2/ball", "sim1/world", "sim2/")] \
        == ["", "world", "world", "ball", "ball", "sim1/world", "sim2/"]
    assert itf.UNPREFIXED.world == "world" and itf.UNPREFIXED.to_core("world") == "world"
    spec = itf.PARAMETER_BY_NAME["frame_prefix"]
    assert check_parameter(spec, "sim2/") is None and check_parameter(spec, "") is None
    for bad in ("/sim2/", "sim 2/", "x" * 65, "sim2/\n"):
        assert check_parameter(spec, bad).startswith("frame_prefix must be letters, digits"), bad

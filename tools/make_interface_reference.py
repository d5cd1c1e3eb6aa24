#!/usr/bin/env python3
"""Write ``tests/data/jazzy_interfaces.json``: the reference that ``tests/test_interfaces.py`` compares our copies
of the Jazzy interface packages (``msgs_config/upstream/``) and whatever package is installed against.

Run once, by hand, with a checkout of each upstream repository (not needed by the tests, which use only the
committed JSON)::

    .venv/bin/python tools/make_interface_reference.py \\
        simulation_interfaces=<checkout of ros-simulation/simulation_interfaces>@1.5.1 \\
        tf2_msgs=<checkout of ros2/geometry2>@jazzy:tf2_msgs

For every ``msg/``, ``srv/`` and ``action/`` file at that revision it records
- the git blob id (``git ls-tree``): byte identity of our copy with upstream;
- the RIHS01 type hash of every type it defines (messages; ``_Request`` / ``_Response`` of a service; ``_Goal``
  / ``_Result`` / ``_Feedback`` of an action), computed by rosbags' ``Typestore.hash_rihs01`` — an
  implementation of REP-2011's hash independent of rosidl — from the upstream text, with the dependencies
  (geometry_msgs, std_msgs, ...) of rosbags' own ROS 2 Jazzy type store.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

OUT = Path(__file__).resolve().parents[1] / "tests" / "data" / "jazzy_interfaces.json"
SEPARATOR = "\n---\n"


def _git(repo: str, *args: str) -> str:
    return subprocess.run(["git", "-C", repo, *args], check=True, capture_output=True, text=True).stdout


def _parts(kind: str, text: str) -> list[tuple[str, str]]:
    """(suffix, message text) of each message a .msg / .srv / .action file defines."""
    lines = text.split("\n")
    sections, current = [], []
    for line in lines:  # a line of three dashes (maybe with trailing blanks) separates the parts
        if line.strip() == "---":
            sections.append("\n".join(current))
            current = []
        else:
            current.append(line)
    sections.append("\n".join(current))
    suffixes = {"msg": [""], "srv": ["_Request", "_Response"], "action": ["_Goal", "_Result", "_Feedback"]}[kind]
    assert len(sections) == len(suffixes), (kind, len(sections))
    return list(zip(suffixes, sections))


def reference(package: str, repo: str, rev: str, subdir: str) -> dict:
    commit = _git(repo, "rev-parse", f"{rev}^{{commit}}").strip()
    prefix = f"{subdir}/" if subdir else ""
    blobs, texts = {}, {}
    for line in _git(repo, "ls-tree", "-r", commit, *([subdir] if subdir else [])).splitlines():
        meta, path = line.split("\t")
        rel = path[len(prefix):]
        kind = rel.split("/")[0]
        if kind in ("msg", "srv", "action") and "/" in rel:
            blobs[rel] = meta.split()[2]
            texts[rel] = _git(repo, "show", f"{commit}:{path}")
    store = get_typestore(Stores.ROS2_JAZZY)
    defined = {}
    for rel, text in texts.items():
        kind, file_name = rel.split("/")
        stem = file_name.rsplit(".", 1)[0]
        for suffix, part in _parts(kind, text):
            name = f"{package}/{kind}/{stem}{suffix}"
            defined[name] = part
    # register everything at once (messages of the package refer to each other)
    types = {}
    for name, text in defined.items():
        # rosbags resolves a bare type name in the kind of the file it reads (``Result`` in an action would be
        # ``pkg/action/Result``); rosidl resolves it in ``pkg/msg``: parse as a msg, register under the real name
        package_name, _, type_name = name.split("/")
        parsed = get_types_from_msg(text, f"{package_name}/msg/{type_name}")
        types[name] = parsed.pop(f"{package_name}/msg/{type_name}")
        types.update(parsed)
    store.register(types)
    hashes = {name: store.hash_rihs01(name) for name in sorted(defined)}
    return {"repository": repo_url(package), "revision": rev, "commit": commit, "subdirectory": subdir,
            "files": dict(sorted(blobs.items())), "type_hashes": hashes}


def repo_url(package: str) -> str:
    return {"simulation_interfaces": "ros-simulation/simulation_interfaces (GitHub)",
            "tf2_msgs": "ros2/geometry2 (GitHub)"}[package]


def main(argv: list[str]) -> int:
    from importlib.metadata import version

    out = {"generated_by": f"tools/make_interface_reference.py (type hashes: rosbags {version('rosbags')})",
           "packages": {}}
    for arg in argv:
        package, rest = arg.split("=", 1)
        repo, _, rev = rest.partition("@")
        rev, _, subdir = rev.partition(":")
        out["packages"][package] = reference(package, repo, rev, subdir)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

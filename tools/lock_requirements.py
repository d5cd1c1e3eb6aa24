#!/usr/bin/env python3
"""Write the lock of every Python dependency: ``requirements/constraints-<distro>.txt``.

``make setup`` installs the requirement files with ``pip install -c requirements/constraints-<distro>.txt``, so a
fresh machine next month installs exactly the versions CI tested, whatever the registry has published since.
This script re-resolves the requirement files (pip's own resolver, ``--dry-run --ignore-installed --report``:
nothing is installed) and writes every distribution pip would install as ``name==version``.

Run it after changing a requirement file (``make lock``, or ``make lock ROS_DISTRO=kilted``), then commit the
constraints file with the change.  Usage::

    .venv/bin/python tools/lock_requirements.py jazzy requirements/ros.txt requirements/build.txt ...
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from datetime import date
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def resolve(requirement_files: list[str]) -> list[tuple[str, str]]:
    """(name, version) of every distribution pip resolves for the files, sorted by name."""
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "report.json"
        command = [sys.executable, "-m", "pip", "install", "--disable-pip-version-check", "--quiet", "--dry-run",
                   "--ignore-installed", "--report", str(report)]
        for path in requirement_files:
            command += ["-r", path]
        subprocess.run(command, check=True, cwd=REPO)
        installs = json.loads(report.read_text())["install"]
    return sorted(((item["metadata"]["name"], item["metadata"]["version"]) for item in installs),
                  key=lambda pair: pair[0].lower())


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    distro, files = argv[0], argv[1:]
    pins = resolve(files)
    out = REPO / "requirements" / f"constraints-{distro}.txt"
    header = [
        f"# Lock of every Python dependency for ROS 2 {distro.capitalize()} ({len(pins)} distributions), written by",
        f"# tools/lock_requirements.py on {date.today().isoformat()} from: {' '.join(files)}.",
        "# `make setup` installs with `pip install -c` this file; regenerate it with `make lock` after changing a",
        "# requirement file, and commit both.",
    ]
    out.write_text("\n".join(header + [f"{name}=={version}" for name, version in pins]) + "\n")
    print(f"lock_requirements.py: {len(pins)} pins written to {out.relative_to(REPO)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

#!/usr/bin/env python3
"""Install ``setup.py``'s ``data_files`` into the running virtualenv: what ``pip install -e`` leaves out.

``make setup`` installs this project in editable mode (``pip install -e .``): the venv imports ``cgp_core``,
``cgp_sim_ros`` and ``msgs_config`` from the checkout itself, so the node, the tests and the compile workers all
use one copy of the sources and one numba cache next to them (``__pycache__``), and an edit can never leave an
installed copy behind.  An editable install puts no ``data_files`` anywhere, and those are the ament layout that
``ros2 run`` and ``ament_index_python`` resolve: ``share/ament_index/resource_index/packages/cgp_sim_ros``,
``share/cgp_sim_ros/`` (package.xml, scenes, parameters, ...) and ``lib/cgp_sim_ros/sim_node``.  This script
copies exactly the list ``setup.py`` gives (read by running ``setup.py`` with ``setuptools.setup`` replaced, so
the list has one home), after clearing what an earlier run put into our own directories (a scene deleted from
the checkout does not linger).  It also removes what a regular, non-editable install of an earlier set-up left
in site-packages (numba's cache files in ``cgp_core/__pycache__`` ...): such a leftover directory would be
imported as an empty namespace package instead of the checkout.

Run with the venv's Python after ``pip install -e .`` (``make setup`` does): ``.venv/bin/python
tools/install_data_files.py``.  colcon and a plain ``pip install .`` install the same files themselves.
"""

from __future__ import annotations

import os
import runpy
import shutil
import sys
import sysconfig
from pathlib import Path

import setuptools

REPO = Path(__file__).resolve().parents[1]
PACKAGE = "cgp_sim_ros"
#: the top-level Python packages setup.py installs (site-packages directories of a regular install)
TOP_LEVEL = ("cgp_core", "cgp_sim_ros", "msgs_config")


def data_files() -> list[tuple[str, list[str]]]:
    """``setup.py``'s ``data_files``: ``[(directory relative to the prefix, [file relative to the repo])]``."""
    captured: dict = {}
    original, setuptools.setup = setuptools.setup, lambda **kwargs: captured.update(kwargs)
    cwd = os.getcwd()
    try:
        os.chdir(REPO)  # setup.py globs and opens paths relative to its directory
        runpy.run_path(str(REPO / "setup.py"), run_name="__main__")
    finally:
        os.chdir(cwd)
        setuptools.setup = original
    return captured["data_files"]


def remove_regular_install_leftovers(site_packages: Path) -> list[Path]:
    """Delete our packages' directories from site-packages where the editable install is in place (pip
    uninstalled the regular install's files but not the numba cache beside them); returns what was removed."""
    if not any(site_packages.glob(f"__editable__*{PACKAGE}*")):
        return []  # not an editable install: these directories are the installed packages
    removed = []
    for name in TOP_LEVEL:
        leftover = site_packages / name
        if leftover.is_dir():
            shutil.rmtree(leftover)
            removed.append(leftover)
    return removed


def install(prefix: Path) -> int:
    """Copy the data files into ``prefix``; returns how many."""
    entries = data_files()
    for own in (prefix / "share" / PACKAGE, prefix / "lib" / PACKAGE):
        shutil.rmtree(own, ignore_errors=True)
    count = 0
    for directory, files in entries:
        target = prefix / directory
        target.mkdir(parents=True, exist_ok=True)
        for name in files:
            shutil.copy2(REPO / name, target / Path(name).name)  # copy2 keeps sim_node's executable bit
            count += 1
    return count


def main() -> int:
    prefix = Path(sys.prefix)
    if prefix == Path(sys.base_prefix):
        print("install_data_files.py: run me with the virtualenv's Python (.venv/bin/python)", file=sys.stderr)
        return 2
    for path in remove_regular_install_leftovers(Path(sysconfig.get_path("purelib"))):
        print(f"install_data_files.py: removed {path} (left over from a regular install)")
    count = install(prefix)
    print(f"install_data_files.py: {count} data files (the ament layout of {PACKAGE}) installed into {prefix}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

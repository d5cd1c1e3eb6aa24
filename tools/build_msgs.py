#!/usr/bin/env python3
"""Build and install the project's interface packages into the running virtualenv.

Run with the venv's Python (``make setup`` does): ``.venv/bin/python tools/build_msgs.py [PACKAGE ...]``
(default: every package below; the Makefile builds each with its own stamp, so only changed ones rebuild).

- ``cgp_sim_msgs`` (``msgs_config/cgp_sim_msgs``): ours, always built.
- ``tf2_msgs`` and ``simulation_interfaces`` (``msgs_config/upstream/``): byte-identical copies of the ROS 2
  Jazzy packages (ros2/geometry2 ``jazzy``; ros-simulation/simulation_interfaces 1.5.1; see
  ``msgs_config/upstream/README.md``), which have no PyPI wheel.  They are built only when no installed package
  of that name is found (:func:`installed_elsewhere`): on a real ROS 2 install (``ros-jazzy-tf2-msgs``,
  ``ros-jazzy-simulation-interfaces``, on ``AMENT_PREFIX_PATH``) the real ones are used and ours never shadow
  them.  A copy we built carries the marker file ``share/<pkg>/BUILT_BY_CGP_SIM`` so that it is rebuilt (not
  mistaken for an installed one) when its sources change.

The ROS 2 wheels from PyPI carry everything rosidl needs except one thing: their exported CMake files
(``<venv>/share/**/*Export.cmake``) name the Python and numpy include directories of the machine the
wheels were built on (``/opt/python/cp3XX-cp3XX/...``).  We re-point those to this venv's own paths
(idempotent), then configure with CMake + Ninja and install into the venv prefix, exactly as
``colcon build`` would install into a workspace's ``install/``.  On a real ROS 2 install none of this is
needed: ``colcon build`` builds ``msgs_config/cgp_sim_msgs`` like any interface package (``msgs_config/upstream``
holds a ``COLCON_IGNORE``: rosdep installs the real tf2_msgs and simulation_interfaces there).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
OWN_PACKAGES = {"cgp_sim_msgs": REPO / "msgs_config" / "cgp_sim_msgs"}
UPSTREAM_DIR = REPO / "msgs_config" / "upstream"
#: built in this order (simulation_interfaces does not depend on tf2_msgs; the order only fixes the log)
UPSTREAM_PACKAGES = {"tf2_msgs": UPSTREAM_DIR / "tf2_msgs",
                     "simulation_interfaces": UPSTREAM_DIR / "simulation_interfaces"}
#: file installed into ``share/<pkg>/`` of every upstream copy this script builds
MARKER = "BUILT_BY_CGP_SIM"
#: a quick proof that the installed package works: its generated Python module imports and instantiates
IMPORT_CHECKS = {
    "cgp_sim_msgs": "from cgp_sim_msgs.msg import ApplyWrench; ApplyWrench(body='x')",
    "tf2_msgs": "from tf2_msgs.msg import TFMessage; TFMessage()",
    "simulation_interfaces": "from simulation_interfaces.srv import SpawnEntity; "
                             "from simulation_interfaces.action import SimulateSteps; SpawnEntity.Request()",
}

# The wheel build machine's paths, as they appear in the exported CMake files.
_FOREIGN_PYTHON_INCLUDE = re.compile(r"/opt/python/cp3\d+-cp3\d+/include/python3\.\d+t?")
_FOREIGN_NUMPY_INCLUDE = re.compile(
    r"/opt/python/cp3\d+-cp3\d+/lib/python3\.\d+t?/site-packages/numpy/(?:_core|core)/include"
)


def repoint_exported_cmake(prefix: Path) -> int:
    """Rewrite the wheels' exported include paths to this interpreter's; returns the number of files changed."""
    import numpy

    python_include = sysconfig.get_paths()["include"]
    numpy_include = numpy.get_include()
    changed = 0
    for path in (prefix / "share").rglob("*.cmake"):
        text = path.read_text(encoding="utf-8", errors="surrogateescape")
        if "/opt/python/" not in text:
            continue
        new = _FOREIGN_NUMPY_INCLUDE.sub(numpy_include, text)
        new = _FOREIGN_PYTHON_INCLUDE.sub(python_include, new)
        if new != text:
            path.write_text(new, encoding="utf-8", errors="surrogateescape")
            changed += 1
    return changed


def _ament_prefixes(prefix: Path, environ: dict) -> list[Path]:
    """The install prefixes searched for packages: ``AMENT_PREFIX_PATH`` (a sourced ROS install or workspace),
    then this venv (where the PyPI wheels install ``share/ament_index`` without setting the variable)."""
    found = [Path(p) for p in environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    return found + ([prefix] if prefix not in found else [])


def installed_elsewhere(package: str, prefix: Path, environ: dict | None = None) -> Path | None:
    """The prefix of an installed ``package`` that this script did not build, or None.

    A package is installed in a prefix when the ament index there lists it (what ``ament_index_python`` and
    ``ros2 run`` look at).  A copy in ``prefix`` carrying our :data:`MARKER` is ours, not "installed": it is
    rebuilt when its sources change."""
    environ = os.environ if environ is None else environ
    for root in _ament_prefixes(prefix, environ):
        if not (root / "share" / "ament_index" / "resource_index" / "packages" / package).is_file():
            continue
        if (root / "share" / package / MARKER).is_file():
            continue
        return root
    return None


def _tools(prefix: Path) -> tuple[str, Path] | str:
    cmake = shutil.which("cmake")
    if cmake is None:
        return "cmake not found on PATH; install it (apt install cmake)"
    ninja = prefix / "bin" / "ninja"
    if not ninja.exists():
        found = shutil.which("ninja")
        if found is None:
            return "ninja not found; `pip install ninja` into the venv"
        ninja = Path(found)
    return cmake, ninja


def build_package(name: str, source: Path, prefix: Path, cmake: str, ninja: Path, env: dict) -> None:
    """Configure, build and install one ament_cmake interface package into ``prefix``."""
    build = prefix / "build" / name
    if build.exists():
        # A stale cache from another source path or Python would silently misconfigure.
        shutil.rmtree(build)
    build.mkdir(parents=True)
    configure = [
        cmake, "-S", str(source), "-B", str(build), "-G", "Ninja",
        f"-DCMAKE_MAKE_PROGRAM={ninja}",
        f"-DCMAKE_PREFIX_PATH={prefix}",
        f"-DCMAKE_INSTALL_PREFIX={prefix}",
        f"-DPython3_EXECUTABLE={sys.executable}",
        "-DPython3_FIND_VIRTUALENV=ONLY",
        "-DBUILD_TESTING=OFF",
        "-DCMAKE_BUILD_TYPE=Release",
    ]
    subprocess.run(configure, check=True, env=env, stdout=subprocess.DEVNULL)
    subprocess.run([str(ninja), "-C", str(build), "install"], check=True, env=env, stdout=subprocess.DEVNULL)
    # The build tree is only needed while building (the next build starts from scratch anyway).
    shutil.rmtree(build, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    prefix = Path(sys.prefix)
    if prefix == Path(sys.base_prefix):
        print("build_msgs.py: run me with the virtualenv's Python (.venv/bin/python)", file=sys.stderr)
        return 2
    packages = {**OWN_PACKAGES, **UPSTREAM_PACKAGES}
    unknown = [name for name in argv if name not in packages]
    if unknown:
        print(f"build_msgs.py: unknown package(s) {', '.join(unknown)}; known: {', '.join(packages)}",
              file=sys.stderr)
        return 2
    wanted = argv or list(packages)

    todo = []
    for name in wanted:
        elsewhere = installed_elsewhere(name, prefix) if name in UPSTREAM_PACKAGES else None
        if elsewhere is not None:
            print(f"build_msgs.py: {name}: using the installed package in {elsewhere} (not building our copy)")
        else:
            todo.append(name)
    if not todo:
        return 0
    tools = _tools(prefix)
    if isinstance(tools, str):
        print(f"build_msgs.py: {tools}", file=sys.stderr)
        return 2
    cmake, ninja = tools

    changed = repoint_exported_cmake(prefix)
    if changed:
        print(f"build_msgs.py: re-pointed Python/numpy include paths in {changed} exported CMake files")
    env = dict(os.environ)
    env["AMENT_PREFIX_PATH"] = os.pathsep.join(str(p) for p in _ament_prefixes(prefix, os.environ))
    env["CMAKE_PREFIX_PATH"] = str(prefix)
    env["PATH"] = f"{prefix / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    for name in todo:
        build_package(name, packages[name], prefix, cmake, ninja, env)
        if name in UPSTREAM_PACKAGES:
            (prefix / "share" / name / MARKER).write_text(
                f"built by cgp_sim's tools/build_msgs.py from {packages[name].relative_to(REPO)} "
                "(see its README.md); delete this package when a real one is installed\n", encoding="utf-8")
        # Prove the result: the generated Python module imports (through the bootstrapper, in a fresh process).
        subprocess.run([sys.executable, "-c", IMPORT_CHECKS[name]], check=True, env=env)
        print(f"build_msgs.py: {name} installed into {prefix}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/env python3
"""Build and install the ``cgp_sim_msgs`` interface package into the running virtualenv.

Run with the venv's Python (``make setup`` does): ``.venv/bin/python tools/build_msgs.py``.

The ROS 2 wheels from PyPI carry everything rosidl needs except one thing: their exported CMake files
(``<venv>/share/**/*Export.cmake``) name the Python and numpy include directories of the machine the
wheels were built on (``/opt/python/cp3XX-cp3XX/...``).  We re-point those to this venv's own paths
(idempotent), then configure with CMake + Ninja and install into the venv prefix, exactly as
``colcon build`` would install into a workspace's ``install/``.  On a real ROS 2 install none of this is
needed: ``colcon build`` builds ``msgs_config/cgp_sim_msgs`` like any interface package.
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
PACKAGE_SRC = REPO / "msgs_config" / "cgp_sim_msgs"

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


def main() -> int:
    prefix = Path(sys.prefix)
    if prefix == Path(sys.base_prefix):
        print("build_msgs.py: run me with the virtualenv's Python (.venv/bin/python)", file=sys.stderr)
        return 2
    cmake = shutil.which("cmake")
    if cmake is None:
        print("build_msgs.py: cmake not found on PATH; install it (apt install cmake)", file=sys.stderr)
        return 2
    ninja = prefix / "bin" / "ninja"
    if not ninja.exists():
        found = shutil.which("ninja")
        if found is None:
            print("build_msgs.py: ninja not found; `pip install ninja` into the venv", file=sys.stderr)
            return 2
        ninja = Path(found)

    changed = repoint_exported_cmake(prefix)
    if changed:
        print(f"build_msgs.py: re-pointed Python/numpy include paths in {changed} exported CMake files")

    build = prefix / "build" / "cgp_sim_msgs"
    if build.exists():
        # A stale cache from another source path or Python would silently misconfigure.
        shutil.rmtree(build)
    build.mkdir(parents=True)
    env = dict(os.environ)
    env["AMENT_PREFIX_PATH"] = str(prefix)
    env["CMAKE_PREFIX_PATH"] = str(prefix)
    env["PATH"] = f"{prefix / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    configure = [
        cmake, "-S", str(PACKAGE_SRC), "-B", str(build), "-G", "Ninja",
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

    # Prove the result: the generated Python module imports (through the bootstrapper, in a fresh process).
    check = "from cgp_sim_msgs.msg import ApplyWrench; ApplyWrench(body='x')"
    subprocess.run([sys.executable, "-c", check], check=True, env=env)
    print(f"build_msgs.py: cgp_sim_msgs installed into {prefix}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

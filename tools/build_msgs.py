#!/usr/bin/env python3
"""Build and install the project's interface packages into the running virtualenv.

Run with the venv's Python (``make setup`` does): ``.venv/bin/python tools/build_msgs.py [PACKAGE ...]``
(default: every package below).  ``--stamps DIR`` (the Makefile's ``.venv/.stamps``): build only the packages
whose build inputs changed since they were last built (their sources, this script, :data:`PYTHON_ONLY_CMAKE`,
the Python; a content hash in ``DIR/msgs-<package>.sha256``), so that an edit of one package, or a checkout that
only touched the files' times, does not rebuild the others.

- ``cgp_sim_msgs`` (``msgs_config/cgp_sim_msgs``): ours, always built.
- ``tf2_msgs`` and ``simulation_interfaces`` (``msgs_config/upstream/``): byte-identical copies of the ROS 2
  Jazzy packages (ros2/geometry2 ``jazzy``; ros-simulation/simulation_interfaces 1.5.1; see
  ``msgs_config/upstream/README.md``), which have no PyPI wheel.  They are built only when no installed package
  of that name is found (:func:`installed_elsewhere`): on a real ROS 2 install (``ros-jazzy-tf2-msgs``,
  ``ros-jazzy-simulation-interfaces``, on ``AMENT_PREFIX_PATH``) the real ones are used and ours never shadow
  them.  A copy we built carries the marker file ``share/<pkg>/BUILT_BY_CGP_SIM`` so that it is rebuilt (not
  mistaken for an installed one) when its sources change.

**Only what a Python node loads, all packages at once.**  The venv build registers only the rosidl generators
and type supports rclpy uses (:data:`PYTHON_ONLY_CMAKE`, included through ``CMAKE_PROJECT_INCLUDE``: the Python
generator, the C generator and type description, the C type-support dispatcher and its fastrtps and
introspection back-ends), not the C++ ones (headers and libraries for rclcpp nodes, whose templates were most of
the compile time); ``--all-generators`` builds everything, as colcon does.  The packages to build are configured
and built side by side (one thread each, ninja's jobs shared through a jobserver when ninja supports one), the
three together taking ~1 min on 2 cores (60.6 s measured on a quiet machine; one after the other with every
generator they took 42 s + 48 s + 5 min 47 s, issue 34).

The ROS 2 wheels from PyPI carry everything rosidl needs except one thing: their exported CMake files
(``<venv>/share/**/*Export.cmake``) name the Python and numpy include directories of the machine the
wheels were built on (``/opt/python/cp3XX-cp3XX/...``).  We re-point those to this venv's own paths
(idempotent), then configure with CMake + Ninja and install into the venv prefix, exactly as
``colcon build`` would install into a workspace's ``install/``.  On a real ROS 2 install none of this is
needed: ``colcon build`` builds ``msgs_config/cgp_sim_msgs`` like any interface package, with every generator
(:data:`PYTHON_ONLY_CMAKE` is this script's, not the package's; ``msgs_config/upstream`` holds a
``COLCON_IGNORE``: rosdep installs the real tf2_msgs and simulation_interfaces there).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
OWN_PACKAGES = {"cgp_sim_msgs": REPO / "msgs_config" / "cgp_sim_msgs"}
UPSTREAM_DIR = REPO / "msgs_config" / "upstream"
#: built in this order (simulation_interfaces does not depend on tf2_msgs; the order only fixes the log)
UPSTREAM_PACKAGES = {"tf2_msgs": UPSTREAM_DIR / "tf2_msgs",
                     "simulation_interfaces": UPSTREAM_DIR / "simulation_interfaces"}
#: file installed into ``share/<pkg>/`` of every upstream copy this script builds
MARKER = "BUILT_BY_CGP_SIM"
#: the CMake file that leaves the C++ generators out of the venv build (``CMAKE_PROJECT_INCLUDE``)
PYTHON_ONLY_CMAKE = REPO / "tools" / "rosidl_python_only.cmake"
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


def build_inputs_hash(name: str, source: Path) -> str:
    """A hash of what a package's build depends on here: its source files, this script and
    :data:`PYTHON_ONLY_CMAKE`, the Python it is built for."""
    digest = hashlib.sha256(f"{sys.executable}\n{sys.version}\n{name}\n".encode())
    files = sorted(p for p in source.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    for path in [Path(__file__).resolve(), PYTHON_ONLY_CMAKE, *files]:
        digest.update(f"{path.relative_to(REPO) if path.is_relative_to(REPO) else path}\n".encode())
        digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


def is_installed(name: str, prefix: Path) -> bool:
    """Whether the ament index in ``prefix`` lists ``name`` (and its Python package is there)."""
    return ((prefix / "share" / "ament_index" / "resource_index" / "packages" / name).is_file()
            and (Path(sysconfig.get_paths(vars={"base": str(prefix), "platbase": str(prefix)})["purelib"])
                 / name).is_dir())


def remove_installed(name: str, prefix: Path) -> None:
    """Delete a copy of ``name`` this script installed before (one built with other generators leaves libraries
    and CMake exports the new build does not overwrite)."""
    site = Path(sysconfig.get_paths(vars={"base": str(prefix), "platbase": str(prefix)})["purelib"])
    for path in [prefix / "share" / name, prefix / "include" / name, site / name,
                 *site.glob(f"{name}-*.egg-info"), *(prefix / "lib").glob(f"lib{name}__*"),
                 *(prefix / "share" / "ament_index" / "resource_index").glob(f"*/{name}")]:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        elif path.exists() or path.is_symlink():
            path.unlink()


class Jobserver:
    """A GNU make jobserver (a named pipe holding ``jobs - 1`` tokens) shared by the ninjas that build side by
    side, so that together they run ``jobs`` compilers, not ``jobs`` each (ninja >= 1.13 takes part when
    ``MAKEFLAGS`` names the pipe; an older one ignores it and runs its own default)."""

    def __init__(self, jobs: int):
        self.jobs = jobs
        self._dir = tempfile.mkdtemp(prefix="cgp_sim_jobserver_")
        self.fifo = os.path.join(self._dir, "fifo")
        os.mkfifo(self.fifo)
        # held open read-write for the lifetime of the builds: the pipe (and its tokens) must outlive any client
        self._fd = os.open(self.fifo, os.O_RDWR)
        os.write(self._fd, b"+" * (jobs - 1))

    def makeflags(self) -> str:
        return f"-j{self.jobs} --jobserver-auth=fifo:{self.fifo}"

    def close(self) -> None:
        os.close(self._fd)
        shutil.rmtree(self._dir, ignore_errors=True)


def build_package(name: str, source: Path, prefix: Path, cmake: str, ninja: Path, env: dict, *,
                  all_generators: bool = False, jobs: int | None = None) -> dict[str, float]:
    """Configure, build and install one ament_cmake interface package into ``prefix``; returns the seconds
    configuring and building took.  ``jobs``: ninja's ``-j`` (default: its own, or the jobserver's in ``env``)."""
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
    if not all_generators:
        configure.append(f"-DCMAKE_PROJECT_INCLUDE={PYTHON_ONLY_CMAKE}")
    started = time.perf_counter()
    _run(name, "configure", configure, env)
    configured = time.perf_counter()
    _run(name, "build", [str(ninja), "-C", str(build), *([f"-j{jobs}"] if jobs else []), "install"], env)
    built = time.perf_counter()
    # The build tree is only needed while building (the next build starts from scratch anyway).
    shutil.rmtree(build, ignore_errors=True)
    return {"configure": configured - started, "build": built - configured}


def _run(name: str, step: str, command: list[str], env: dict) -> None:
    """Run one build step quietly; on failure, show its output (the builds run side by side: not interleaved)."""
    done = subprocess.run(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if done.returncode != 0:
        tail = "\n".join(done.stdout.strip().splitlines()[-40:])
        raise RuntimeError(f"{name}: {step} failed (exit status {done.returncode}):\n{tail}")


def _build_and_check(name: str, prefix: Path, cmake: str, ninja: Path, env: dict, all_generators: bool,
                     stamps: Path | None, log_lock: threading.Lock) -> None:
    packages = {**OWN_PACKAGES, **UPSTREAM_PACKAGES}
    remove_installed(name, prefix)
    if stamps is not None:
        (stamps / f"msgs-{name}.sha256").unlink(missing_ok=True)
    times = build_package(name, packages[name], prefix, cmake, ninja, env, all_generators=all_generators)
    if name in UPSTREAM_PACKAGES:
        (prefix / "share" / name / MARKER).write_text(
            f"built by cgp_sim's tools/build_msgs.py from {packages[name].relative_to(REPO)} "
            "(see its README.md); delete this package when a real one is installed\n", encoding="utf-8")
    # Prove the result: the generated Python module imports (through the bootstrapper, in a fresh process).
    subprocess.run([sys.executable, "-c", IMPORT_CHECKS[name]], check=True, env=env)
    if stamps is not None:
        stamps.mkdir(parents=True, exist_ok=True)
        (stamps / f"msgs-{name}.sha256").write_text(build_inputs_hash(name, packages[name]) + "\n")
    with log_lock:
        print(f"build_msgs.py: {name} installed into {prefix} (configure {times['configure']:.1f} s, "
              f"build {times['build']:.1f} s)", flush=True)


def main(argv: list[str] | None = None) -> int:
    packages = {**OWN_PACKAGES, **UPSTREAM_PACKAGES}
    parser = argparse.ArgumentParser(prog="build_msgs.py", description=__doc__.splitlines()[0])
    parser.add_argument("packages", nargs="*", metavar="PACKAGE",
                        help=f"the packages to build (default: all; known: {', '.join(packages)})")
    parser.add_argument("--stamps", type=Path, metavar="DIR",
                        help="skip a package whose build inputs are unchanged since its last build (hashes in DIR)")
    parser.add_argument("--all-generators", action="store_true",
                        help="build every rosidl generator (C++ too), as colcon does; default: what rclpy loads")
    parser.add_argument("--jobs", "-j", type=int, default=os.cpu_count() or 2,
                        help="compilers running at once, all packages together (default: the CPUs)")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    prefix = Path(sys.prefix)
    if prefix == Path(sys.base_prefix):
        print("build_msgs.py: run me with the virtualenv's Python (.venv/bin/python)", file=sys.stderr)
        return 2
    unknown = [name for name in args.packages if name not in packages]
    if unknown:
        parser.error(f"unknown package(s) {', '.join(unknown)}; known: {', '.join(packages)}")
    wanted = args.packages or list(packages)

    todo = []
    for name in wanted:
        elsewhere = installed_elsewhere(name, prefix) if name in UPSTREAM_PACKAGES else None
        if elsewhere is not None:
            print(f"build_msgs.py: {name}: using the installed package in {elsewhere} (not building our copy)")
            continue
        stamp = args.stamps / f"msgs-{name}.sha256" if args.stamps else None
        if (stamp is not None and stamp.is_file() and is_installed(name, prefix)
                and stamp.read_text().strip() == build_inputs_hash(name, packages[name])):
            continue  # built from these very inputs already
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
    print(f"build_msgs.py: building {', '.join(todo)} ("
          f"{'every generator' if args.all_generators else 'the Python, C and C type-support generators'}, "
          f"{args.jobs} jobs)", flush=True)
    started = time.perf_counter()
    jobserver = Jobserver(args.jobs) if len(todo) > 1 and args.jobs > 1 else None
    if jobserver is not None:
        env["MAKEFLAGS"] = jobserver.makeflags()
    elif len(todo) == 1:
        env.pop("MAKEFLAGS", None)  # ninja's own -j (the CPUs + 2), not a make's that ran us
    lock = threading.Lock()
    try:
        with ThreadPoolExecutor(max_workers=len(todo)) as pool:
            futures = {name: pool.submit(_build_and_check, name, prefix, cmake, ninja, env, args.all_generators,
                                         args.stamps, lock) for name in todo}
        failed = {name: f.exception() for name, f in futures.items() if f.exception() is not None}
    finally:
        if jobserver is not None:
            jobserver.close()
    for error in failed.values():
        print(f"build_msgs.py: {error}", file=sys.stderr)
    if failed:
        return 1
    print(f"build_msgs.py: {len(todo)} package(s) built in {time.perf_counter() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""`colcon build` of a ROS 2 workspace holding this repo builds both packages (cgp_sim_msgs with rosidl,
cgp_sim_ros as ament_python) and the result runs — the workflow the README gives for a Jazzy install, here
against the venv's ROS wheels as the underlay."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
VENV = Path(sys.prefix)


def test_colcon_build_of_a_workspace_holding_the_repo(tmp_path):
    colcon = VENV / "bin" / "colcon"
    if not colcon.exists():
        pytest.fail("colcon is not installed in the venv (requirements/dev.txt): run `make setup`")
    # the repo as a user would clone it: tracked files (and new ones), without the venv or build products
    src = tmp_path / "ws" / "src" / "cgp_sim"
    files = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                           capture_output=True, text=True, check=True).stdout.split()
    for name in files:
        if (REPO / name).is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / name, src / name)
    ws = tmp_path / "ws"
    env = dict(os.environ, AMENT_PREFIX_PATH=str(VENV), CMAKE_PREFIX_PATH=str(VENV),
               PATH=f"{VENV / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}")
    build = subprocess.run(
        [str(colcon), "build", "--base-paths", "src", "src/cgp_sim/msgs_config",
         "--cmake-args", f"-DPython3_EXECUTABLE={sys.executable}", "-DBUILD_TESTING=OFF"],
        cwd=ws, env=env, capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    for package in ("cgp_sim_msgs", "cgp_sim_ros"):
        assert f"Finished <<< {package}" in build.stdout, build.stdout[-2000:]
    # a workspace build is a normal interface package, with every generator: the C++ headers and type supports
    # too (only the venv's build, tools/build_msgs.py, leaves out what a Python node does not load)
    msgs = ws / "install" / "cgp_sim_msgs"
    assert (msgs / "include" / "cgp_sim_msgs" / "cgp_sim_msgs" / "msg" / "contacts.hpp").is_file()
    assert (msgs / "lib" / "libcgp_sim_msgs__rosidl_typesupport_cpp.so").is_file()
    # our copies of ROS 2's tf2_msgs and simulation_interfaces (msgs_config/upstream, COLCON_IGNORE) are not
    # built in a workspace: the installed ones (the underlay's; rosdep's on a ROS install) are used, unshadowed
    for package in ("tf2_msgs", "simulation_interfaces"):
        assert package not in build.stdout and not (ws / "install" / package).exists(), package

    install = ws / "install"
    node = install / "cgp_sim_ros" / "lib" / "cgp_sim_ros" / "sim_node"
    assert node.is_file() and os.access(node, os.X_OK)
    site = f"lib/python{sys.version_info.major}.{sys.version_info.minor}/site-packages"
    # the shipped robots (the `arm` scene's arm7.urdf, ...) are in the package, as its scenes are
    for urdf in ("arm.urdf", "arm7.urdf"):
        assert (install / "cgp_sim_ros" / site / "msgs_config" / "robots" / urdf).is_file(), urdf
        assert (install / "cgp_sim_ros" / "share" / "cgp_sim_ros" / "robots" / urdf).is_file(), urdf
    run_env = dict(env, AMENT_PREFIX_PATH=os.pathsep.join([str(install / "cgp_sim_ros"),
                                                         str(install / "cgp_sim_msgs"), str(VENV)]),
                   PYTHONPATH=os.pathsep.join([str(install / "cgp_sim_ros" / site),
                                               str(install / "cgp_sim_msgs" / site)]))
    # what `ros2 run cgp_sim_ros sim_node` does after sourcing install/setup.bash: exec the file.  With the kernels
    # as plain Python (NUMBA_DISABLE_JIT): the workspace's copy of the sources has no compile cache of its own, and
    # its compile workers took ~32 s of the suite's time here to test the layout, which the JIT does not touch
    # (the compile on a first start: tests/test_compile_workers.py)
    ran = subprocess.run([str(node), "--scene", "zero_g", "--realtime", "false", "--duration", "0.5"],
                         env=dict(run_env, NUMBA_DISABLE_JIT="1"), capture_output=True, text=True, timeout=120)
    assert ran.returncode == 0, ran.stdout + ran.stderr
    assert "duration 0.5 s of simulated time reached after 30 ticks" in ran.stdout + ran.stderr
    assert str(install / "cgp_sim_ros") in ran.stdout + ran.stderr  # the workspace's copy ran, not the venv's

"""The runtime under everything is the one the project names: ROS 2 Jazzy (rclpy 7.1, Fast DDS 2.14) from the
pinned wheels, and every installed dependency at the version the lock pins (what CI tested)."""

from __future__ import annotations

import re
import sys
from importlib import metadata
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _distro() -> str:
    """The distribution this venv was set up for (the Makefile: .venv is Jazzy, .venv-kilted is Kilted)."""
    return "kilted" if Path(sys.prefix).name == ".venv-kilted" else "jazzy"


def _pins(distro: str) -> dict[str, str]:
    text = (REPO / "requirements" / f"constraints-{distro}.txt").read_text()
    return {_canonical(name): version for name, version in re.findall(r"^([A-Za-z0-9_.\-]+)==(\S+)$", text, re.M)}


def _canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def test_every_installed_dependency_is_at_its_locked_version():
    pins = _pins(_distro())
    installed = {_canonical(d.metadata["Name"]): d.version for d in metadata.distributions()}
    locked_and_installed = {name: (installed[name], pin) for name, pin in pins.items() if name in installed}
    assert len(locked_and_installed) >= 0.9 * len(pins), "most locked distributions are not installed here"
    assert {n: v for n, v in locked_and_installed.items() if v[0] != v[1]} == {}


def test_ros_is_jazzy_with_fast_dds_2_14():
    rclpy = metadata.version("ros-rclpy")
    if _distro() == "jazzy":
        assert rclpy.startswith("7.1."), rclpy
        assert metadata.version("ros-jazzy-rclpy") == "7.1.6"
        assert metadata.version("ros-jazzy-common-interfaces") == "5.3.6"
        assert metadata.version("ros-fastrtps").startswith("2.14."), metadata.version("ros-fastrtps")
    else:
        assert rclpy.startswith("9."), rclpy
    import rclpy as rclpy_module  # the bootstrapped import works, and the RMW is Fast DDS
    from rclpy.utilities import get_rmw_implementation_identifier

    assert rclpy_module is not None and get_rmw_implementation_identifier() == "rmw_fastrtps_cpp"

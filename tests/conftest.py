"""Shared test fixtures.

ROS tests run the real node as its own process (the installed ``cgp-sim`` script) and observe it from this
process over DDS.  Isolation: every test session gets its own ``ROS_DOMAIN_ID`` (set before rclpy loads, and
inherited by the node processes), so parallel runs on one machine never see each other.  Discovery is waited
for with deadlines (``count_publishers`` / ``count_subscribers``), never with fixed sleeps.
"""

from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

# Ctrl-C as a terminal sends it, whatever this process inherited: a shell starts a background job (`make test &`,
# `nohup`) with SIGINT ignored, and an ignored signal stays ignored in every process started from here, so the tests
# that send SIGINT to a node, a sweep or a compile (and expect it to stop) would see it do nothing.  A handler set
# here is reset to the default in each child at exec.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

REPO = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent

# One domain per session, chosen before anything imports rclpy.  0..101 are valid with Fast DDS' default port
# mapping; avoid 0 (the default other tools use).
# With pytest-xdist (`make test` runs two workers), the controller picks the session's domain and every worker
# takes its own next to it: worker gwK uses domain + K (wrapping within 1..101), so two workers' nodes never see
# each other.
if "CGP_SIM_TEST_DOMAIN" not in os.environ:
    os.environ["CGP_SIM_TEST_DOMAIN"] = str(random.Random(os.getpid() ^ time.time_ns()).randint(1, 101))
_WORKER = os.environ.get("PYTEST_XDIST_WORKER", "")
_OFFSET = int(_WORKER[2:]) if _WORKER.startswith("gw") and _WORKER[2:].isdigit() else 0
os.environ["ROS_DOMAIN_ID"] = str((int(os.environ["CGP_SIM_TEST_DOMAIN"]) - 1 + _OFFSET) % 101 + 1)
os.environ.setdefault("RCUTILS_LOGGING_BUFFERED_STREAM", "0")
os.environ["PYTHONUNBUFFERED"] = "1"


def pytest_addoption(parser):
    parser.addoption("--run-soak", action="store_true", default=False, help="run the long soak tests")


#: the test files that take longest, in seconds (setup + call + teardown of all their tests; a warm `pytest -n 2
#: --durations=0` run on the 2-core machine, 2026-12-07, with that day's changes to test_colcon and
#: test_node_interface): only the order in which xdist hands out the files depends on it (below)
FILE_SECONDS = {
    "test_compile_workers.py": 75, "test_robustness_commands.py": 68, "test_robustness_node_inputs.py": 63,
    "test_node_interface.py": 60, "test_node_robots.py": 60, "test_robustness_faults.py": 59, "test_gallery.py": 47,
    "test_foxglove.py": 45, "test_render.py": 44, "test_sweep.py": 32, "test_node_bag.py": 29,
    "test_node_sim_services.py": 28, "test_node_graph.py": 25, "test_node_robot_spawn.py": 24,
    "test_node_bounded_output.py": 23, "test_solver_regions.py": 23, "test_joint_integrators.py": 21,
    "test_colcon.py": 20, "test_node_worlds.py": 20, "test_jit_parity.py": 15, "test_docs.py": 15,
    "test_mesh_fast_path.py": 14,
}


def _expected_seconds(file: str, items) -> float:
    """A file's expected time: :data:`FILE_SECONDS`, else 4 s a test that starts a node and 0.1 s any other."""
    if Path(file).name in FILE_SECONDS:
        return FILE_SECONDS[Path(file).name]
    return sum(4.0 if "start_node" in item.fixturenames else 0.1 for item in items)


def pytest_collection_modifyitems(config, items):
    # The longest files first.  `make test`'s xdist workers take whole files (--dist loadfile, in collection order:
    # --no-loadscope-reorder), each the next one when it is nearly done; by name, or by xdist's own order (most tests
    # first), the files of one or two long tests (a colcon build, a compile without cache, 13 gallery nodes) came
    # last and one worker ran them while the other had nothing left.  Within a file the order is kept.
    by_file: dict[str, list] = {}
    for item in items:
        by_file.setdefault(item.nodeid.split("::")[0], []).append(item)
    ranked = sorted(by_file, key=lambda f: -_expected_seconds(f, by_file[f]))  # (stable: ties keep their order)
    items[:] = [item for f in ranked for item in by_file[f]]

    if config.getoption("--run-soak"):
        return
    skip = pytest.mark.skip(reason="soak test: run with `make soak`")
    for item in items:
        if "soak" in item.keywords:
            item.add_marker(skip)


def cgp_sim_executable() -> str:
    """The installed console script (what `make setup` put in the venv)."""
    path = VENV_BIN / "cgp-sim"
    if not path.exists():
        found = shutil.which("cgp-sim")
        if found is None:
            pytest.fail("cgp-sim is not installed: run `make setup` first")
        return found
    return str(path)


class NodeProcess:
    """A cgp_sim node running as a separate process; stdout+stderr captured to a log file."""

    def __init__(self, args: list[str], log_path: Path, command: list[str] | None = None, env: dict | None = None):
        self.log_path = log_path
        self._log = open(log_path, "wb")
        self.command = (command or [cgp_sim_executable()]) + list(args)
        self.proc = subprocess.Popen(self.command, stdout=self._log, stderr=subprocess.STDOUT,
                                     env=env or os.environ.copy(), start_new_session=True)

    def log(self) -> str:
        """Everything the node wrote so far (also after :meth:`stop` closed our end of the log file: an assertion
        message that reads the log after a failed stop must show the log, not raise)."""
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def alive(self) -> bool:
        return self.proc.poll() is None

    def send(self, sig: int) -> None:
        if self.alive():
            self.proc.send_signal(sig)

    def wait(self, timeout: float) -> int:
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"node did not exit within {timeout} s; log:\n{self.log()[-4000:]}") from None

    def stop(self, timeout: float = 20.0) -> int | None:
        """SIGINT, then wait; SIGKILL if it hangs (which fails no test by itself: the caller asserts)."""
        if self.alive():
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()
        return self.proc.returncode


@pytest.fixture
def start_node(tmp_path):
    """Start `cgp-sim <args>`; every node started is stopped at teardown."""
    started: list[NodeProcess] = []

    def _start(*args: str, command: list[str] | None = None, env: dict | None = None) -> NodeProcess:
        node = NodeProcess(list(args), tmp_path / f"node{len(started)}.log", command=command, env=env)
        started.append(node)
        return node

    yield _start
    for node in started:
        node.stop()


@pytest.fixture(scope="session")
def ros():
    """rclpy initialised once for the session in this (observer) process."""
    import rclpy

    rclpy.init()
    yield rclpy
    rclpy.try_shutdown()


@pytest.fixture
def probe(ros, request):
    """An observer node in this process with helpers to wait for and collect messages."""
    from ros_probe import Probe

    p = Probe(f"probe_{os.getpid()}_{abs(hash(request.node.nodeid)) % 100000}")
    yield p
    p.close()

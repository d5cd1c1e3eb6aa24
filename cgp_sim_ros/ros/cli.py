"""``cgp-sim`` (and ``ros2 run cgp_sim_ros sim_node``): run the simulation node.

Every node parameter is also a flag (``--rate-hz 120`` ≡ ``--ros-args -p rate_hz:=120.0``); flags win over
``--ros-args -p``.  Everything after ``--ros-args`` goes to ROS (remaps, namespaces, parameter files).

Shutdown: Ctrl-C (SIGINT) or SIGTERM ends the run cleanly after the current tick — the bag is finished
(summary, metadata.yaml) and its location printed.  A second Ctrl-C aborts at once.  Within 2 s in every case:
if the current tick (or the start-up) has not ended :data:`STOP_GRACE_S` after the signal — a long compiled
kernel holds the main thread, where Python runs its signal handlers only between bytecodes — the stop
watchdog (:class:`StopWatchdog`, a thread woken by the signal itself through ``signal.set_wakeup_fd``) finishes
the bag with every tick before the current one, prints its summary and exits with status 0.

Exit status: 0 after a clean shutdown (signal or ``duration`` reached); 2 for a configuration the node cannot
start with (an invalid flag or parameter value, a scene that does not load, unparsable ROS arguments, an
existing bag directory), with the reason on stderr and nothing published.
"""

from __future__ import annotations

import argparse
import signal
import socket
import sys
import threading
import time
from os import _exit as exit_now  # the process ends at once: no atexit, no DDS teardown (see StopWatchdog)

from .. import interface as itf

#: after SIGINT / SIGTERM, how long the current tick may go on before the watchdog stops the node without it
STOP_GRACE_S = 1.0
#: ... and by when the process is gone, whatever it was doing (the bag finished within the difference)
STOP_DEADLINE_S = 1.9


class StopWatchdog:
    """Stops the node within :data:`STOP_DEADLINE_S` of a SIGINT / SIGTERM even while the main thread is stuck in
    a tick.  Python runs a signal handler in the main thread between bytecodes only, so during a long compiled
    (nogil) kernel the handler — and with it the stop — waits for the kernel.  But CPython's C-level handler
    writes the signal number to the wakeup fd at once; this thread waits on that fd.  If the main loop has not
    begun its normal shutdown :data:`STOP_GRACE_S` after the signal, the thread finishes every open recording
    (:data:`cgp_sim_ros.ros.recorder.OPEN_RECORDERS`: the writer thread writes what is queued — the ticks before
    the current one — the summary and metadata.yaml), prints the summary and ends the process with status 0.
    If the normal shutdown is under way but not done by the deadline, it ends the process too."""

    def __init__(self):
        self._read, write = socket.socketpair()
        write.setblocking(False)
        self._write = write
        signal.set_wakeup_fd(write.fileno(), warn_on_full_buffer=False)
        #: set by the main thread when it leaves its loop (normal shutdown begins) and when it is done
        self.shutting_down = threading.Event()
        self.done = threading.Event()
        self._thread = threading.Thread(target=self._run, name="cgp-sim-stop-watchdog", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """The node is done: the watchdog's thread ends (and the wakeup fd goes back to Python's default), so that
        nothing of the node outlives ``main()`` (tests/test_node_graph.py checks no thread of ours is left)."""
        self.done.set()
        signal.set_wakeup_fd(-1)
        self._write.close()  # the thread's recv() returns b"": it ends
        self._thread.join(timeout=STOP_DEADLINE_S)
        self._read.close()

    def _run(self) -> None:
        while True:
            try:
                data = self._read.recv(64)
            except OSError:
                return
            if not data:
                return
            if signal.SIGINT in data or signal.SIGTERM in data:
                break
        signalled = time.monotonic()
        if self.shutting_down.wait(STOP_GRACE_S):
            if self.done.wait(max(0.0, STOP_DEADLINE_S - (time.monotonic() - signalled))):
                return
            _say("the shutdown took longer than its deadline: exiting now (the bag may lack its summary: "
                 "cgp-sim-render and mcap read it anyway)")
            exit_now(0)
        from .recorder import OPEN_RECORDERS

        _say(f"the current tick is still running {STOP_GRACE_S:g} s after the signal: stopping without it")
        for recorder in list(OPEN_RECORDERS):
            recorder.close(timeout=max(0.05, STOP_DEADLINE_S - 0.05 - (time.monotonic() - signalled)))
            _say(recorder.summary_text().removeprefix("cgp-sim: "))
        exit_now(0)


def _say(text: str) -> None:
    try:
        print(f"cgp-sim: {text}", file=sys.stderr, flush=True)
    except Exception:  # noqa: BLE001 - a closed stderr must not keep the process alive
        pass


def _bool(text: str) -> bool:
    lowered = text.strip().lower()
    if lowered in ("1", "true", "yes", "on"):
        return True
    if lowered in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cgp-sim",
        description="Rigid bodies and boid flocks of the CGP lecture, live on ROS 2 and recorded to MCAP.",
        epilog="ROS arguments follow --ros-args, e.g. --ros-args -r __ns:=/sim1 -p rate_hz:=120.0. "
               "Built-in scenes: " + ", ".join(_builtin_scenes()),
    )
    for spec in itf.PARAMETERS:
        if spec.flag is None:
            continue
        kind = _bool if isinstance(spec.default, bool) else type(spec.default)
        parser.add_argument(spec.flag, dest=spec.name, type=kind, default=None, metavar=spec.name.upper(),
                            help=f"{spec.description} (default: {spec.default!r})")
    parser.add_argument("--list-scenes", action="store_true",
                        help="print the built-in scenes with what each shows, and exit")
    return parser


def _builtin_scenes() -> list[str]:
    from cgp_core.scene import builtin_scene_names

    return builtin_scene_names()


def _scene_list(width: int = 100) -> str:
    """Every built-in scene with its description, for ``--list-scenes``."""
    import textwrap

    from cgp_core.scene import scene_description

    names = _builtin_scenes()
    column = max(map(len, names)) + 2
    blocks = []
    for name in names:
        text = scene_description(name) or "(no description)"
        lines = textwrap.wrap(text, width - column) or [""]
        blocks.append("\n".join([name.ljust(column) + lines[0]] + [" " * column + line for line in lines[1:]]))
    return "\n".join(blocks)


def _ros_argument_errors() -> tuple[type[Exception], ...]:
    """What rcl raises for unparsable ``--ros-args`` (malformed remaps, -p without a rule, flags after
    --ros-args, an unreadable --params-file)."""
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

    return tuple(getattr(_rclpy, name) for name in ("RCLInvalidROSArgsError", "UnknownROSArgsError")
                 if hasattr(_rclpy, name))


def _scene_argument(flag: str | None, argv: list[str]) -> str | None:
    """The scene the node will load, as the command line names it: ``--scene`` (which wins, as the node's
    parameter override), else the last ``-p scene:=...`` / ``--param scene:=...`` (also ``-p <node>:scene:=...``)
    among the ROS arguments; None when neither names one (the default scene, or a --params-file)."""
    if flag is not None:
        return flag
    found = None
    ros_arguments = False
    for word, following in zip(argv, argv[1:] + [""]):
        if word == "--ros-args":
            ros_arguments = True
        elif word == "--":
            ros_arguments = False
        elif ros_arguments and word in ("-p", "--param"):
            name, separator, value = following.partition(":=")
            if separator and name.rpartition(":")[2] == "scene":
                found = value
    return found


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv if argv is None else argv)
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions

    from ..warmup import compile_missing_kernels
    from .node import SimNode
    from .parameters import ConfigError

    try:
        args = build_parser().parse_args(rclpy.utilities.remove_ros_args(argv)[1:])
    except _ros_argument_errors() as exc:
        # rcl's message: the rule it could not parse first, then C source locations (noise for a user).
        reason = str(exc).split(", at /")[0]
        if type(exc).__name__ == "UnknownROSArgsError":
            reason = f"{reason} after --ros-args are not ROS arguments"
        print(f"cgp-sim: invalid ROS arguments: {reason} (cgp-sim's own flags go before --ros-args; see "
              "--help)", file=sys.stderr)
        return 2
    if args.list_scenes:
        print(_scene_list())
        return 0
    # A scene named on the command line is read before anything slow happens: right after an install or an edit
    # the kernels' compile below takes half a minute or more, and a typo in a path should not wait for it.  The
    # node is handed what was loaded (a scene with a big mesh is not loaded twice).  (A scene set in a
    # --params-file is checked by the node, after the compile.)
    scene = _scene_argument(args.scene, argv)
    loaded = None
    if scene is not None:
        from cgp_core.scene import SceneError, load_scene

        try:
            loaded = load_scene(scene)
        except SceneError as exc:
            print(f"cgp-sim: scene: {exc}", file=sys.stderr)
            return 2
    # Right after an install or an edit of the kernels' sources numba has nothing cached: compile the kernels
    # the scene runs in parallel processes now (the default scene's: 24 s on 2 cores, benchmarks/bench_compile.py),
    # not one by one in the first tick (about 40 s of CPU; a scene of hulls or robots: every kernel).
    try:
        compile_missing_kernels(lambda text: print(f"cgp-sim: {text}", file=sys.stderr, flush=True), loaded)
    except KeyboardInterrupt:
        print("cgp-sim: interrupted while compiling the kernels (the next start compiles what is missing)",
              file=sys.stderr)
        return 130
    overrides = [Parameter(spec.name, value=getattr(args, spec.name))
                 for spec in itf.PARAMETERS if spec.flag is not None and getattr(args, spec.name) is not None]

    # Our own signal handling (not rclpy's): a stop request is a flag the loop checks between callbacks, so a
    # tick is never cut in half and the bag is closed by this thread, in order.
    stop = {"requested": False}

    def request_stop(signum, frame):
        if stop["requested"] and signum == signal.SIGINT:
            raise KeyboardInterrupt  # second Ctrl-C: abort now
        stop["requested"] = True

    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    signal.signal(signal.SIGINT, request_stop)
    signal.signal(signal.SIGTERM, request_stop)
    watchdog = StopWatchdog()
    try:
        node = SimNode(parameter_overrides=overrides, loaded_scene=None if loaded is None else (scene, loaded))
    except ConfigError as exc:
        print(f"cgp-sim: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        watchdog.close()
        return 2
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        while rclpy.ok() and not node.finished and not stop["requested"]:
            executor.spin_once(timeout_sec=0.05)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        watchdog.shutting_down.set()
        node.close()
        if node.recorder is not None:
            print(node.recorder.summary_text(), flush=True)
        executor.remove_node(node)
        node.destroy_node()  # with it the DDS participant: before the process exits (SimNode.destroy_node)
        executor.shutdown()
        rclpy.try_shutdown()
        watchdog.close()
    return 0


def entry() -> None:
    """The ``cgp-sim`` command and ``sim_node``: :func:`main`, then the process ends at once with its status.

    By the time ``main`` returns everything of ours is finished — the bag closed and synced, the node and its DDS
    participant destroyed, rclpy shut down, our threads joined — and what an ordinary exit would still run are
    native libraries' static destructors: Fast DDS's participant factory (a known crash at exit: rosbag2#1311,
    Fast-DDS#1906/#3495) and numba's TBB pool (numba#10556).  One of them crashed a node with SIGSEGV after
    "duration ... reached; shutting down" in CI (the gallery test, 13 nodes stopping at once).  Exiting with
    ``os._exit`` (``exit_now``) skips them; stdout and stderr are flushed first.  ``faulthandler`` is on for the
    whole run, so a crash before this point still prints every thread's Python stack to stderr."""
    import faulthandler

    faulthandler.enable()
    status = main()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 - a closed stream must not keep the process alive
            pass
    exit_now(status)


if __name__ == "__main__":
    entry()

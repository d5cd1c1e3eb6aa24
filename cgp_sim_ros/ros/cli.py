"""``cgp-sim`` (and ``ros2 run cgp_sim_ros sim_node``): run the simulation node.

Every node parameter is also a flag (``--rate-hz 120`` ≡ ``--ros-args -p rate_hz:=120.0``); flags win over
``--ros-args -p``.  Everything after ``--ros-args`` goes to ROS (remaps, namespaces, parameter files).

Shutdown: Ctrl-C (SIGINT) or SIGTERM ends the run cleanly after the current tick — the bag is finished
(summary, metadata.yaml) and its location printed.  A second Ctrl-C aborts at once.

Exit status: 0 after a clean shutdown (signal or ``duration`` reached); 2 for a configuration the node cannot
start with (an invalid flag or parameter value, a scene that does not load, unparsable ROS arguments, an
existing bag directory), with the reason on stderr and nothing published.
"""

from __future__ import annotations

import argparse
import signal
import sys

from .. import interface as itf


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
    # Right after an install or an edit of the kernels' sources numba has nothing cached: compile the kernels
    # in parallel processes now (about 25 s on 2 cores), not one by one in the first tick (about 40 s).
    try:
        compile_missing_kernels(lambda text: print(f"cgp-sim: {text}", file=sys.stderr, flush=True))
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
    try:
        node = SimNode(parameter_overrides=overrides)
    except ConfigError as exc:
        print(f"cgp-sim: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        while rclpy.ok() and not node.finished and not stop["requested"]:
            executor.spin_once(timeout_sec=0.05)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.close()
        if node.recorder is not None:
            print(node.recorder.summary_text(), flush=True)
        executor.remove_node(node)
        node.destroy_node()  # with it the DDS participant: before the process exits (SimNode.destroy_node)
        executor.shutdown()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The node's recording: every topic it publishes and every command it receives, into a rosbag2-style MCAP
bag (:class:`cgp_sim_ros.wire.bag.BagWriter`: its own thread, chunked, lz4, crash-safe).

What is recorded at what rate: every message of every topic, except what the level-of-detail plan
(:mod:`cgp_sim_ros.drawing.detail`) records less often — the node decides per tick and calls :meth:`Recorder.write`
only for what goes into the bag; the plan is in the bag's ``custom_data`` (``cgp_sim.recorded_every_n_ticks``,
topic → N) and on ``~/events``.

Timestamps: log time = publish time = the simulation time of the tick (ns).  That is what ``/clock`` carries
in the same bag, so ``ros2 bag play --clock`` / Foxglove replays line up with ``use_sim_time`` consumers, and
the simulation time never goes backwards (a reset keeps the clock running), so readers see ordered times.
"""

from __future__ import annotations

import time
from pathlib import Path

from ..wire.bag import BagOptions, BagWriter, bag_path_occupied
from .parameters import ConfigError

INFRASTRUCTURE_TOPICS = ("/rosout", "/parameter_events")

#: the recorders not closed yet, for the stop watchdog of ``cgp-sim`` (cgp_sim_ros/ros/cli.py), which finishes
#: their bags from its own thread when a signal's stop cannot wait for the current tick to end
OPEN_RECORDERS: list = []


def bag_directory(text: str) -> Path | None:
    """The bag directory the parameter ``bag`` names (None for ""), resolved once (``~``, symlinks and ``..``
    as the OS resolves them): the recording writes inside it and nowhere else (a lexical ``a/new/../bag`` would
    make ``mkdir -p`` create ``a/new``).  Checked before anything is built or published: recording into an
    old bag would mix two runs, so an existing, non-empty one is a :class:`ConfigError`.  A path that cannot
    even be examined (a name longer than NAME_MAX...) is not a configuration error here: the recorder
    reports it as it reports any unwritable location, and the simulation goes on."""
    if not text:
        return None
    path = Path(text).expanduser()
    try:
        path = path.resolve()
    except (OSError, RuntimeError):  # a symlink loop, ...: left for the recorder to report
        path = path.absolute()
    try:
        occupied = bag_path_occupied(path)
    except OSError:
        occupied = False
    if occupied:
        raise ConfigError(f"bag: {str(path)!r} already exists and is "
                          f"{'not empty' if path.is_dir() else 'not a directory'}; choose a new "
                          "directory (a bag is never overwritten)")
    return path


def type_name(msg_class) -> str:
    """``pkg/msg/Type`` of a generated rclpy message class."""
    return f"{msg_class.__module__.split('.')[0]}/msg/{msg_class.__name__}"


class Recorder:
    def __init__(self, node, directory: Path, *, max_bytes: int = 0, max_duration_s: float = 0.0,
                 custom_data: dict | None = None):
        self.node = node
        self.directory = directory.resolve()
        self._error_reported = False
        self._own_data = {"recorder": "cgp_sim", "scene": str(node.world.scene.source)}
        self.writer = BagWriter(self.directory, BagOptions(max_bytes=max_bytes, max_duration_s=max_duration_s),
                                custom_data={**self._own_data, **(custom_data or {})})
        self.started = time.monotonic()
        OPEN_RECORDERS.append(self)
        # Every topic the node itself publishes or subscribes to (not rclpy's own /rosout, /parameter_events).
        self.add_endpoints([*node.publishers, *node.subscriptions])
        self.report_errors()

    def add_endpoints(self, endpoints) -> None:
        """Record these publishers' / subscriptions' topics too (a spawned body's, mid-recording: the bag gets
        new channels from here on, and metadata.yaml counts them).  Topics already recorded are left as they are
        (a body deleted and spawned again under its name keeps its channel)."""
        for endpoint in endpoints:
            if endpoint.topic_name not in INFRASTRUCTURE_TOPICS:
                self.writer.add_topic(endpoint.topic_name, type_name(endpoint.msg_type), endpoint.qos_profile)

    def write(self, topic: str, data: bytes, stamp_ns: int) -> None:
        self.writer.write(topic, data, stamp_ns, stamp_ns)

    def begin_tick(self) -> None:
        """A real-time tick starts: the writer thread leaves the cores to it until :meth:`end_tick`
        (BagWriter.hold: bounded, so a bag never falls behind for it)."""
        self.writer.hold()

    def end_tick(self) -> None:
        """The tick's messages are all written: the writer thread may take them now (BagWriter.wake)."""
        self.writer.wake()

    def set_custom_data(self, custom_data: dict) -> None:
        """The node's entries of the bag's ``custom_data`` from now on (the level-of-detail plan)."""
        self.writer.set_custom_data({**self._own_data, **custom_data})

    @property
    def recording(self) -> bool:
        """False once the bag cannot be written (see :attr:`BagWriter.error`)."""
        return self.writer.error is None

    def report_errors(self) -> None:
        """Log the writer's first error once (disk full, unwritable directory...); the simulation goes on."""
        if self.writer.error and not self._error_reported:
            self._error_reported = True
            self.node.get_logger().error(f"recording failed: {self.writer.error}")

    def size_bytes(self) -> int:
        """Bytes of the bag's files on disk so far."""
        total = 0
        for path in self.writer.files:
            try:
                total += path.stat().st_size
            except OSError:
                pass
        return total

    def close(self, timeout: float | None = None) -> None:
        """Finish the bag (BagWriter.close; ``timeout``: give up waiting for the writer after that long)."""
        self.writer.close(timeout)
        if self in OPEN_RECORDERS:
            OPEN_RECORDERS.remove(self)
        self.report_errors()

    def summary_text(self) -> str:
        if not self.writer.files:  # the directory or its first file could not be created
            return (f"cgp-sim: no bag recorded ({self.writer.dropped_messages} messages not recorded): "
                    f"{self.writer.error}")
        files = ", ".join(p.name for p in self.writer.files)
        lines = [f"cgp-sim: bag in {self.directory} ({files}; {self.writer.committed_messages} messages"
                 + (f", {self.writer.dropped_messages} dropped" if self.writer.dropped_messages else "") + ")"]
        if self.writer.error:
            lines.append(f"cgp-sim: recording error: {self.writer.error}")
        lines += [
            "  look at it: open the .mcap file in Foxglove (app.foxglove.dev or the desktop app: drag and drop),",
            f"             or on a ROS 2 install: ros2 bag info {self.directory}",
            f"                                   ros2 bag play {self.directory} --clock  (rviz2 with Fixed Frame"
            " 'world', use_sim_time:=true)",
        ]
        return "\n".join(lines)

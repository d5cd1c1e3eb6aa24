"""The node's ROS interface, defined in one place: every topic, service and parameter with its type, QoS and
meaning (the README's interface table is this file, in prose).

All names are relative (``~/`` = the node's name, default ``cgp_sim``), so ``--ros-args -r __ns:=/robot1``
and ``-r __node:=sim`` and per-topic remaps work.  ``/clock`` is absolute by convention.

Published (frame ``world`` unless said otherwise; all stamps are simulation time):

==============================  ===============================  ===================================================
``~/bodies/poses``              geometry_msgs/PoseArray          every body's COM pose, in scene order
``~/bodies/<body>/odom``        nav_msgs/Odometry                pose in ``world``; ``child_frame_id`` = body name;
                                                                 twist in the body frame (nav_msgs convention)
``~/flocks/<flock>/poses``      geometry_msgs/PoseArray          every boid's pose; orientation = its fish frame
                                                                 (x along the velocity)
``~/flocks/<flock>/stats``      cgp_sim_msgs/FlockStats          the flock's order parameters (polarization, milling,
                                                                 centroid, radius of gyration, mean nearest-
                                                                 neighbour distance, speeds), every tick
``~/markers``                   visualization_msgs/MarkerArray   bodies as their shapes, flocks as spheres or fish;
                                                                 namespaces ``ground``, ``bodies/<body>``,
                                                                 ``flocks/<flock>``; DELETEALL first after a reset
``~/events``                    std_msgs/String                  one line per service call, rejected command
                                                                 batch and world event (audit trail; recorded)
``/clock``                      rosgraph_msgs/Clock              simulation time, once per tick
==============================  ===============================  ===================================================

Subscribed:

==============================  ===============================  ===================================================
``~/apply_wrench``              cgp_sim_msgs/ApplyWrench         force at a point + couple, for one tick, a while or
                                                                 until cleared (see msg/ApplyWrench.msg)
``~/bodies/<body>/wrench``      geometry_msgs/WrenchStamped      force at the COM + couple for one tick; frame_id
                                                                 ``""``/``world`` or the body's name
==============================  ===============================  ===================================================

Services (std_srvs): ``~/reset`` (Trigger), ``~/pause`` (SetBool), ``~/step`` (Trigger, one tick while paused),
``~/clear_wrenches`` (Trigger).
"""

from __future__ import annotations

from dataclasses import dataclass

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

WORLD_FRAME = "world"

# State topics: reliable so RViz / Foxglove (reliable by default) and best-effort subscribers both match;
# KEEP_LAST so a subscriber that never reads cannot make the publisher block or grow memory.
STATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
# /clock: as rclpy / rclcpp's own clock QoS expects (a reliable writer also serves best-effort readers).
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
# Commands: reliable, a deep enough queue for bursts; the node bounds its own pending queue as well.
COMMAND_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)

TOPIC_BODY_POSES = "~/bodies/poses"
TOPIC_BODY_ODOM = "~/bodies/{body}/odom"
TOPIC_BODY_WRENCH = "~/bodies/{body}/wrench"
TOPIC_FLOCK_POSES = "~/flocks/{flock}/poses"
TOPIC_FLOCK_STATS = "~/flocks/{flock}/stats"  # cgp_sim_msgs/FlockStats (cgp_sim_ros/flock_stats.py)
TOPIC_MARKERS = "~/markers"
TOPIC_EVENTS = "~/events"
TOPIC_CLOCK = "/clock"
TOPIC_APPLY_WRENCH = "~/apply_wrench"
SERVICE_RESET = "~/reset"
SERVICE_PAUSE = "~/pause"
SERVICE_STEP = "~/step"
SERVICE_CLEAR_WRENCHES = "~/clear_wrenches"


@dataclass(frozen=True)
class ParameterSpec:
    name: str
    default: object
    description: str
    read_only: bool = False
    minimum: float | None = None
    maximum: float | None = None
    flag: str | None = None  # the `cgp-sim` command-line flag, if any


PARAMETERS: tuple[ParameterSpec, ...] = (
    ParameterSpec("scene", "default", "Scene file path, or a built-in scene name (default, boxes, ...).",
                  read_only=True, flag="--scene"),
    ParameterSpec("rate_hz", 60.0, "Ticks per second; the tick dt = 1/rate_hz of simulated time. Settable at "
                  "run time (the new dt applies from the next tick).", minimum=1.0, maximum=10000.0,
                  flag="--rate-hz"),
    ParameterSpec("substeps", 0, "Physics sub-steps per tick for the rigid bodies (0 = the scene's "
                  "world.substeps).", read_only=True, minimum=0, maximum=1000, flag="--substeps"),
    ParameterSpec("realtime", True, "true: ticks paced to the wall clock; false: as fast as possible (same "
                  "results, same dt).", flag="--realtime"),
    ParameterSpec("start_paused", False, "Start paused (time stopped, nothing published yet) until ~/pause "
                  "is called with data: false, or ~/step steps it: other nodes can connect before the first tick.",
                  read_only=True, flag="--start-paused"),
    ParameterSpec("duration", 0.0, "Simulated seconds to run before the node exits by itself; 0 = until "
                  "shutdown.", minimum=0.0, flag="--duration"),
    ParameterSpec("bag", "", "Directory to record an MCAP bag into (must not exist yet); empty = no recording.",
                  read_only=True, flag="--bag"),
    ParameterSpec("bag_max_size", 0, "Split the bag into a new .mcap file after this many bytes; 0 = never.",
                  read_only=True, minimum=0, flag="--bag-max-size"),
    ParameterSpec("bag_max_duration", 0.0, "Split the bag into a new .mcap file after this many seconds of "
                  "simulated time; 0 = never.", read_only=True, minimum=0.0, flag="--bag-max-duration"),
    ParameterSpec("seed", -1, "Random seed of the flocks (flock i gets seed + i); -1 = the scene's own seeds.",
                  read_only=True, minimum=-1, flag="--seed"),
    ParameterSpec("max_force", 1e5, "Largest accepted wrench force magnitude [N]; larger commands are "
                  "rejected.", minimum=0.0, flag="--max-force"),
    ParameterSpec("max_torque", 1e5, "Largest accepted wrench torque magnitude [N m].", minimum=0.0,
                  flag="--max-torque"),
    ParameterSpec("markers_every", 1, "Publish ~/markers every N ticks (a level-of-detail option for huge "
                  "flocks; 1 = every tick).", minimum=1, maximum=10000, flag="--markers-every"),
)
PARAMETER_BY_NAME = {p.name: p for p in PARAMETERS}

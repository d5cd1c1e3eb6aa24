"""The node's ROS interface, defined in one place: every topic, service and parameter with its type and
meaning, and the limits on what the node accepts (docs/interface.md is this file, in prose).

ROS-free (names, defaults and numbers only), so that the level-of-detail planner and the docs tests read it
without rclpy; the QoS profile each topic is offered with is in
:mod:`cgp_sim_ros.ros.qos`: ``STATE_QOS`` for the published state topics, ``CLOCK_QOS`` for ``/clock``,
``COMMAND_QOS`` for the command topics, ``EVENTS_QOS`` for ``~/events``, ``TF_QOS`` / ``TF_STATIC_QOS`` for TF.

All names are relative (``~/`` = the node's name, default ``cgp_sim``), so ``--ros-args -r __ns:=/robot1``
and ``-r __node:=sim`` and per-topic remaps work.  ``/clock`` is absolute by convention.

Published (frame ``world`` unless said otherwise — every frame id with ``frame_prefix`` in front; all stamps are
simulation time):

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
                                                                 ``flocks/<flock>``, ``contacts/points`` and
                                                                 ``contacts/forces`` (``contact_markers``);
                                                                 DELETEALL first after a reset; bounded by the
                                                                 level of detail (drawing/detail.py)
``~/static_markers``            visualization_msgs/MarkerArray   the static meshes (``bodies/<body>``), latched
                                                                 (transient local, as ``/tf_static``): sent when
                                                                 they change, a DELETEALL first
``~/contacts``                  cgp_sim_msgs/Contacts            the contacts of the tick (entities, point, normal,
                                                                 separation, normal and friction impulse; at most
                                                                 MAX_CONTACTS_PER_MESSAGE, the strongest) and each
                                                                 touching body's contact force and torque
                                                                 (parameter ``contacts``)
``~/events``                    std_msgs/String                  one line per service call, rejected command
                                                                 batch and world event (audit trail; recorded);
                                                                 transient local, the last 100 lines
                                                                 (``EVENTS_QOS``): a late subscriber asking for
                                                                 them reads the start-up's lines too
``/clock``                      rosgraph_msgs/Clock              simulation time, once per tick
==============================  ===============================  ===================================================

Subscribed:

==============================  ===============================  ===================================================
``~/apply_wrench``              cgp_sim_msgs/ApplyWrench         force at a point + couple, for one tick, a while or
                                                                 until cleared (see msg/ApplyWrench.msg)
``~/bodies/<body>/wrench``      geometry_msgs/WrenchStamped      force at the COM + couple for one tick; frame_id
                                                                 ``""``/``world`` or the body's name
==============================  ===============================  ===================================================

Per robot of the scene (``robots:``; :mod:`cgp_sim_ros.ros.robots`) or spawned (``~/spawn_entity``: they appear
with it and go when it is deleted), under ``~/robots/<robot>/``:

- ``joint_states`` (sensor_msgs/JointState, published every tick, ``STATE_QOS``): the robot's movable 1-dof joints
  in URDF order (mimic followers included), position, velocity and effort (the tick's mean), SI units, stamped
  with the tick's simulation time; ``header.frame_id`` empty.  Reliable, so that robot_state_publisher's and
  topic_based_ros2_control's SensorDataQoS (best-effort) readers and RViz's reliable ones all match.
- ``robot_description`` (std_msgs/String, ``LATCHED_QOS``: reliable, transient local, depth 1, as
  robot_state_publisher offers it): the URDF as loaded (xacro expanded); sent on the first tick and when the
  robots change.
- ``joint_commands`` (sensor_msgs/JointState, subscribed, ``COMMAND_QOS``), exactly as topic_based_ros2_control
  sends it: ``name`` plus any of ``position`` / ``velocity`` / ``effort``; per joint the array that has an entry
  for it chooses the drive (position > velocity > effort); a command holds until the next one.  Queued and
  applied between ticks; rejections (unknown joint, NaN, ...) named on the log and ``~/events`` as the wrench
  commands' are.
- ``joint_trajectory`` (trajectory_msgs/JointTrajectory, subscribed, ``COMMAND_QOS``): followed through the
  position drives with joint_trajectory_controller's interpolation (cubic between points with velocities, linear
  without; :mod:`cgp_core.robots.trajectory`), from ``header.stamp`` in simulation time (0: when taken); a new
  trajectory replaces the robot's current one, a ``joint_commands`` message stops it.  Either replaces the
  robot's scene trajectory (a scene's ``robots[].trajectory``) until a reset or a load: the ROS command wins.

Services (std_srvs): ``~/reset`` (Trigger), ``~/pause`` (SetBool), ``~/step`` (Trigger, one tick while paused),
``~/clear_wrenches`` (Trigger).

TF (``tf2_msgs/TFMessage``, absolute names as every tf2 user expects): ``/tf`` every tick with ``world`` →
``<body>`` for every movable body (``child_frame_id`` = the Odometry's), ``/tf_static`` (transient local) with
the fixed bodies, sent again whenever that set or a fixed body's pose changes.  Robots: every URDF link frame as
``<robot>/<link>`` (:meth:`Frames.link`; the root link's parent is ``world``, every other link's its URDF parent
link), the moving ones on ``/tf``, the fixed-joint ones (and a fixed base's root) on ``/tf_static``; a robot's
link bodies are not on TF as bodies (their frames are the links').

``simulation_interfaces`` (ROS 2's simulator standard, Jazzy 1.5.1; implemented in
:mod:`cgp_sim_ros.ros.sim_services`, every call also a line on ``~/events``):

==============================  =====================================================================
``~/get_simulator_features``    GetSimulatorFeatures: what is supported, ``spawn_formats: [yaml, stl, obj]``
``~/spawn_entity``              SpawnEntity: ``{body: <scene entry>}`` / ``{flock: <scene entry>}`` YAML
``~/delete_entity``             DeleteEntity: a body or a flock
``~/get_entities``              GetEntities: names (bodies, then flocks), regex / sphere filters
``~/get_entities_states``       GetEntitiesStates: names and states
``~/get_entity_state``          GetEntityState: COM pose, world-frame twist, last tick's acceleration
``~/set_entity_state``          SetEntityState: teleport a body (momenta from the twist) / move a flock
``~/reset_simulation``          ResetSimulation: scopes STATE, SPAWNED, ALL (time keeps running)
``~/get_simulation_state``      GetSimulationState: PLAYING / PAUSED / STOPPED / QUITTING
``~/set_simulation_state``      SetSimulationState
``~/step_simulation``           StepSimulation: exactly ``steps`` ticks while paused, replies when done
``~/simulate_steps`` (action)   SimulateSteps: the same with feedback per tick and cancel
==============================  =====================================================================

With ``foxglove:=true`` all of the above is also served over a Foxglove WebSocket (``foxglove_host``,
``foxglove_port``): the same topics as channels, the same commands and services (see
:mod:`cgp_sim_ros.ros.foxglove_server`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

WORLD_FRAME = "world"
#: what `frame_prefix` may be: TF frame characters, no leading '/' (tf2 frame ids are relative), at most 64 long
FRAME_PREFIX_PATTERN = re.compile(r"[A-Za-z0-9_./-]{0,64}")


@dataclass(frozen=True)
class Frames:
    """The TF frame ids the node writes and reads, with the ``frame_prefix`` parameter applied as
    robot_state_publisher applies its own (prepended verbatim: ``sim1/`` gives ``sim1/world`` and ``sim1/ball``),
    so that several simulators on one graph share ``/tf`` without their frames colliding.

    Outgoing: every header's ``frame_id`` is :attr:`world`; a body's frame (``/tf``'s and the odometry's
    ``child_frame_id``) is :meth:`body`.  Incoming (wrench commands, spawn and state requests): a frame id is
    read as cgp_core names it (:meth:`to_core`): the world is ``""``, ``world`` or the prefixed world, a body
    its name with or without the prefix."""

    prefix: str = ""

    @property
    def world(self) -> str:
        return self.prefix + WORLD_FRAME

    def body(self, name: str) -> str:
        return self.prefix + name

    def link(self, robot: str, link: str) -> str:
        """A robot's URDF link frame: ``<prefix><robot>/<link>`` — the robot's name keeps two robots loaded from
        one URDF apart (RViz's RobotModel display / Foxglove's URDF layer: TF prefix ``<prefix><robot>``)."""
        return f"{self.prefix}{robot}/{link}"

    def to_core(self, frame_id: str) -> str:
        """``frame_id`` as cgp_core's wrench and state checks name frames (the prefix removed); other ids are
        returned as they are, for those checks to refuse by their own rules."""
        if self.prefix and frame_id.startswith(self.prefix) and len(frame_id) > len(self.prefix):
            return frame_id[len(self.prefix):]
        return frame_id


#: the frames without a prefix (the default)
UNPREFIXED = Frames()

#: how model:fish flocks may be drawn: "auto" (cgp_sim_ros/drawing/detail.py chooses) or a detail of
#: drawing.shapes.FISH_DETAILS
FISH_DETAIL_CHOICES = ("auto", "full", "low")

TOPIC_BODY_POSES = "~/bodies/poses"
TOPIC_BODY_ODOM = "~/bodies/{body}/odom"
TOPIC_BODY_WRENCH = "~/bodies/{body}/wrench"
TOPIC_FLOCK_POSES = "~/flocks/{flock}/poses"
# cgp_sim_msgs/FlockStats (cgp_core/boids/order.py, cdr.FlockStatsSerializer)
TOPIC_FLOCK_STATS = "~/flocks/{flock}/stats"
TOPIC_MARKERS = "~/markers"
# the static meshes' markers, latched (issue 38: a 500k-triangle mesh was re-sent every second on ~/markers)
TOPIC_STATIC_MARKERS = "~/static_markers"
# cgp_sim_msgs/Contacts (cgp_core/solver/report.py, cdr.ContactsSerializer)
TOPIC_CONTACTS = "~/contacts"
TOPIC_EVENTS = "~/events"
TOPIC_CLOCK = "/clock"
TOPIC_APPLY_WRENCH = "~/apply_wrench"
TOPIC_TF = "/tf"
# per robot (issue 36): sensor_msgs/JointState out and in, the URDF latched (std_msgs/String)
TOPIC_ROBOT_JOINT_STATES = "~/robots/{robot}/joint_states"
TOPIC_ROBOT_JOINT_COMMANDS = "~/robots/{robot}/joint_commands"
TOPIC_ROBOT_DESCRIPTION = "~/robots/{robot}/robot_description"
# trajectory_msgs/JointTrajectory in, followed through the position drives (cgp_sim_ros/trajectory.py)
TOPIC_ROBOT_JOINT_TRAJECTORY = "~/robots/{robot}/joint_trajectory"
TOPIC_TF_STATIC = "/tf_static"
SERVICE_RESET = "~/reset"
SERVICE_PAUSE = "~/pause"
SERVICE_STEP = "~/step"
SERVICE_CLEAR_WRENCHES = "~/clear_wrenches"
# simulation_interfaces (names relative to the node, as Gazebo's ros_gz_sim has them)
SERVICE_GET_SIMULATOR_FEATURES = "~/get_simulator_features"
SERVICE_SPAWN_ENTITY = "~/spawn_entity"
SERVICE_DELETE_ENTITY = "~/delete_entity"
SERVICE_GET_ENTITIES = "~/get_entities"
SERVICE_GET_ENTITIES_STATES = "~/get_entities_states"
SERVICE_GET_ENTITY_STATE = "~/get_entity_state"
SERVICE_SET_ENTITY_STATE = "~/set_entity_state"
SERVICE_RESET_SIMULATION = "~/reset_simulation"
SERVICE_GET_SIMULATION_STATE = "~/get_simulation_state"
SERVICE_SET_SIMULATION_STATE = "~/set_simulation_state"
SERVICE_STEP_SIMULATION = "~/step_simulation"
# the rest of simulation_interfaces 1.5 (issue 36): worlds, the spawnables, batches, entity info and bounds, named poses
SERVICE_GET_AVAILABLE_WORLDS = "~/get_available_worlds"
SERVICE_LOAD_WORLD = "~/load_world"
SERVICE_UNLOAD_WORLD = "~/unload_world"
SERVICE_GET_CURRENT_WORLD = "~/get_current_world"
SERVICE_GET_SPAWNABLES = "~/get_spawnables"
SERVICE_SPAWN_ENTITIES = "~/spawn_entities"
SERVICE_GET_ENTITY_INFO = "~/get_entity_info"
SERVICE_SET_ENTITY_INFO = "~/set_entity_info"
SERVICE_GET_ENTITY_BOUNDS = "~/get_entity_bounds"
SERVICE_GET_NAMED_POSES = "~/get_named_poses"
SERVICE_GET_NAMED_POSE_BOUNDS = "~/get_named_pose_bounds"
ACTION_SIMULATE_STEPS = "~/simulate_steps"


@dataclass(frozen=True)
class ParameterSpec:
    name: str
    default: object
    description: str
    read_only: bool = False
    minimum: float | None = None
    maximum: float | None = None
    flag: str | None = None  # the `cgp-sim` command-line flag, if any
    choices: tuple | None = None  # the values a string parameter may take
    pattern: re.Pattern | None = None  # what a string parameter must match (whole), said in `pattern_text`
    pattern_text: str = ""


PARAMETERS: tuple[ParameterSpec, ...] = (
    ParameterSpec("scene", "default", "Scene file path, or a built-in scene name (default, zero_g, pyramid, ...; "
                  "`cgp-sim --list-scenes` lists them with what each shows).",
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
    ParameterSpec("markers_every", 0, "Redraw each flock's marker every N ticks, in N parts published one per "
                  "tick (~/markers itself goes out every tick); 0 = automatic: every tick unless the flock markers "
                  "would exceed 32 MB/s, then as often as fits (see cgp_sim_ros/drawing/detail.py; the choice is "
                  "logged at start-up).", minimum=0, maximum=10000, flag="--markers-every"),
    ParameterSpec("fish_detail", "auto", "How model:fish flocks are drawn: full (10 triangles per fish), low (3: "
                  "the outline seen from above and the tail fin) or auto (full unless the markers would exceed "
                  "32 MB/s at the tick rate).", flag="--fish-detail", choices=FISH_DETAIL_CHOICES),
    ParameterSpec("bag_flock_poses_every", 0, "Record ~/flocks/<flock>/poses in the bag every N ticks (they are "
                  "published every tick); 0 = automatic: every tick unless the flocks' poses would exceed 32 MB/s, "
                  "then as often as fits. Written into the bag's metadata (custom_data).", read_only=True,
                  minimum=0, maximum=10000, flag="--bag-flock-poses-every"),
    ParameterSpec("pin_threads", True, "While a flock runs on numba's thread pool (2,000 boids or more): the "
                  "tick's thread on a CPU of its own, every other thread (the pool's workers, the bag writer, DDS) "
                  "on the others (Linux, 2 CPUs or more; cgp_core/jit.py ThreadPlacement: on 2 cores it cut the "
                  "15k-fish real-time tick's p99 from ~13 to ~10 ms). false: the OS places every thread. Logged "
                  "when it changes.", flag="--pin-threads"),
    ParameterSpec("contacts", True, "Publish (and record) ~/contacts every tick: every contact point with its "
                  "entities, normal, separation, normal and friction impulse over the tick, and every touching "
                  "body's mean contact force and torque about its COM (cgp_sim_msgs/Contacts; "
                  "cgp_core/solver/report.py); computed only while someone takes it (a subscriber, the bag, the live "
                  "view, the contact markers). false: the topic does not exist.",
                  read_only=True, flag="--contacts"),
    ParameterSpec("contact_markers", False, "Draw the contacts on ~/markers: namespace contacts/points (a "
                  "SPHERE_LIST of the contact points) and contacts/forces (one ARROW per contact: the contact force "
                  "on entity_b, contact_force_scale metres per newton); drawn by RViz, Foxglove and cgp-sim-render.",
                  read_only=True,
                  flag="--contact-markers"),
    ParameterSpec("contact_force_scale", 0.01, "Length of the contact force arrows (contact_markers) per newton "
                  "[m/N]: 0.01 draws a 2 kg box's m g (19.6 N) as 0.2 m.", read_only=True, minimum=1e-9,
                  maximum=1e3, flag="--contact-force-scale"),
    ParameterSpec("frame_prefix", "", "Prepended to every TF frame id the node publishes (world, the bodies' "
                  "frames; headers and child_frame_id) and accepted in front of the frame ids it is sent, as "
                  "robot_state_publisher's frame_prefix: several simulators on one ROS graph (one /tf) keep their "
                  "frames apart, e.g. `sim1/` gives `sim1/world` -> `sim1/ball`. Letters, digits, _ . / -, no "
                  "leading /, at most 64 characters.", read_only=True, flag="--frame-prefix",
                  pattern=FRAME_PREFIX_PATTERN,
                  pattern_text="letters, digits, _ . / - (no leading /), at most 64 characters"),
    ParameterSpec("spawn_timeout", 30.0, "Seconds a spawn_entity request's preparation (reading, parsing, building "
                  "and drawing the entity, in the spawn worker process) may take; a longer one is stopped and "
                  "refused (OPERATION_FAILED, saying so) and the requests behind it go on.", minimum=0.1,
                  maximum=3600.0, flag="--spawn-timeout"),
    ParameterSpec("foxglove", False, "Serve a live view to the Foxglove app over WebSocket (Foxglove SDK): "
                  "every topic as the same CDR bytes, the simulation time, wrench commands and the services "
                  "(cgp_sim_ros/ros/foxglove_server.py).", read_only=True, flag="--foxglove"),
    ParameterSpec("foxglove_host", "127.0.0.1", "Address the Foxglove WebSocket server listens on (127.0.0.1: "
                  "this machine only; 0.0.0.0: every interface, and anyone who reaches it can push the bodies "
                  "and reset the simulation).", read_only=True, flag="--foxglove-host"),
    ParameterSpec("foxglove_port", 8765, "TCP port of the Foxglove WebSocket server (8765: the app's default); "
                  "0 = a free port chosen by the OS, printed at start-up.", read_only=True, minimum=0,
                  maximum=65535, flag="--foxglove-port"),
)
PARAMETER_BY_NAME = {p.name: p for p in PARAMETERS}

#: rclpy's own parameter (every node has it; declared by rclpy, described by this node).  Issue 27, finding 9:
#: with use_sim_time true a node's timers run on /clock; this node publishes /clock from its timer, so it would
#: wait forever for its own first tick.  Gazebo's behaviour is the reference: the simulator is the time source,
#: its stepping is paced by the wall clock whatever use_sim_time says, and with it true its ROS clock (what
#: rclpy's get_clock() returns) follows the /clock it publishes, as every other node's on the graph does.  Not
#: refused: launch files pass use_sim_time:=true to every node of a simulation, the simulator included.
USE_SIM_TIME = ParameterSpec(
    "use_sim_time", False, "rclpy's own: with true, this node's ROS clock follows /clock, which this node "
    "publishes itself (one message per tick); its stepping is paced by the wall clock either way (the tick "
    "timer runs on steady time), so true or false, at start-up or at run time, the simulation runs as before "
    "(Gazebo's behaviour: the simulator is the time source). Every message is stamped with simulation time "
    "regardless.")
USE_SIM_TIME_NOTE = ("use_sim_time is true: this node's ROS clock follows the /clock it publishes; its ticks are "
                     "paced by the wall clock as before (the simulator is the time source, as in Gazebo)")

# ---- limits on what the node accepts (the command path: cgp_sim_ros/ros/commands.py; the Foxglove live view's
# client input: cgp_sim_ros/ros/foxglove_server.py)

#: commands waiting for the next tick; beyond this, the oldest are dropped (and counted, and reported)
MAX_PENDING_COMMANDS = 2000
#: how often (wall seconds) rejected-command reports and rate checks are summarized in the log
REPORT_PERIOD_S = 2.0
#: larger than any valid ApplyWrench / WrenchStamped: their only unbounded fields are the strings `body` and
#: `header.frame_id`, names of at most MAX_NAME_LENGTH (255) characters (≈ 620 serialized bytes in all).
#: Anything larger is dropped on arrival, before it is decoded or recorded.
MAX_COMMAND_BYTES = 1024
#: a ~/robots/<robot>/joint_commands message larger than this is dropped unread: 4 arrays of a few hundred joints
#: with names of at most MAX_NAME_LENGTH characters fit many times over
MAX_JOINT_COMMAND_BYTES = 65536
#: a ~/robots/<robot>/joint_trajectory message larger than this is dropped unread (10,000 points of 7 joints with
#: positions, velocities and accelerations are ~1.8 MB)
MAX_TRAJECTORY_BYTES = 4 * 1024 * 1024
#: the commands handed to their handlers in one executor turn take at most this long (wall seconds; the rest in the
#: next turn, after the timer had its chance), and the inbox thread takes at most this long in one go
COMMAND_BATCH_S = 0.002

# ---- limits on what a tick sends (issue 38; the markers' level of detail: cgp_sim_ros/drawing/detail.py)

#: contacts in one ~/contacts message (and drawn with contact_markers): a tick with more sends the ones with the
#: largest impulse (normal + friction), in the solver's order; the wrenches are always every body's total
#: (~150 bytes a contact: 2,048 are ~0.3 MB)
MAX_CONTACTS_PER_MESSAGE = 2048

"""The cgp_sim node: a thin, timer-driven adapter between ``cgp_core.World`` and the ROS graph.

Per tick (one timer callback): drain the validated wrench and joint commands into the world → ``World.step()`` →
serialize the state once per message (numpy-built CDR, :mod:`cgp_sim_ros.ros.messages`) → publish those bytes
and hand the same bytes to the recorder and the live view.  No physics here: every equation lives in
``cgp_core``.  What is published, and the one path every message takes, is :mod:`cgp_sim_ros.ros.publishing`;
what comes in and how it is checked, :mod:`cgp_sim_ros.ros.commands` (topics), :mod:`cgp_sim_ros.ros.parameters`
(parameters) and :mod:`cgp_sim_ros.ros.sim_services` (service requests).

Threading: one single-threaded executor runs the timer, the subscriptions and the services, so they never
interleave with a step and need no locks.  The bag is written on its own thread (:mod:`cgp_sim_ros.wire.bag`).
With ``foxglove:=true`` a Foxglove WebSocket server (:mod:`cgp_sim_ros.ros.foxglove_server`) gets the same
bytes; what its clients send reaches the node through the same executor (a guard condition).  While a flock
big enough for numba's thread pool runs (``pin_threads``), the executor's thread — the tick's — has a CPU of
its own and every other thread the others (:mod:`cgp_sim_ros.ros.process`, with the node's other tuning of
its process).

Bad input (what a node on a shared graph must expect):

- commands: dropped when larger than any valid command, validated, queued in a bounded queue; a rejection is
  logged once per kind of problem and then summarized every two seconds (:mod:`cgp_sim_ros.ros.commands`).
- parameters: checked at start-up (a :class:`~cgp_sim_ros.ros.parameters.ConfigError`: ``cgp-sim`` exits
  with status 2 and the reason) and at run time (the parameter callback refuses the change with the reason);
  an override of a parameter the node does not have is warned about (:mod:`cgp_sim_ros.ros.parameters`).
- recording: the bag path is resolved once (``~``, symlinks, ``..``) and nothing is written outside that
  directory; an existing, non-empty bag directory is a ``ConfigError``
  (:func:`cgp_sim_ros.ros.recorder.bag_directory`); a location that cannot be written (beneath a regular
  file, a name too long, disk full...) is logged once with the path and the reason, and the simulation and
  publishing go on without recording.
"""

from __future__ import annotations

import time
from pathlib import Path

from rcl_interfaces.msg import ParameterDescriptor, ParameterType, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from std_srvs.srv import SetBool, Trigger

from cgp_core.scene import SceneError
from cgp_core.world import World, WorldEvent

from .. import interface as itf
from ..drawing import detail as lod
from . import process
from .commands import CommandInputs
from .inbox import CommandInbox
from .messages import robot_names
from .pace import BatchReport, RateCheck
from .parameters import ConfigError, coerce, read_parameters, refusal
from .publishing import TickPublisher
from .sim_services import SimulationInterfaces


class SimNode(Node):
    """The simulation node (``cgp-sim``; ``ros2 run cgp_sim_ros sim_node``): a :class:`cgp_core.world.World`
    ticked by a timer, its state published, recorded and served.

    Its topics, services, action and parameters — names, types, defaults, meaning, limits — are defined in
    :mod:`cgp_sim_ros.interface` (QoS: :mod:`cgp_sim_ros.ros.qos`).  The node itself is the tick
    (:meth:`tick`), its own four services (``~/reset``, ``~/pause``, ``~/step``, ``~/clear_wrenches``), the
    run-time parameter changes and the reports; the rest is done by its collaborators:

    - :attr:`outputs` (:class:`~cgp_sim_ros.ros.publishing.TickPublisher`): every publisher, what a tick
      publishes, ``~/events``; every message published, recorded and shown through one method;
    - :attr:`commands` (:class:`~cgp_sim_ros.ros.commands.CommandInputs`): the command subscriptions, their
      validation, the bounded queue for the next tick, the rejection reports;
    - :attr:`sim` (:class:`~cgp_sim_ros.ros.sim_services.SimulationInterfaces`): ROS 2's
      ``simulation_interfaces`` services and action;
    - :attr:`recorder` (:class:`~cgp_sim_ros.ros.recorder.Recorder`, with ``bag``) and :attr:`foxglove`
      (:class:`~cgp_sim_ros.ros.foxglove_server.FoxgloveServer`, with ``foxglove:=true``), else None;
    - :attr:`threads` (:class:`~cgp_sim_ros.ros.process.ThreadPinning`) and the rest of
      :mod:`cgp_sim_ros.ros.process`: the tuning of the process for the tick.

    What the collaborators use of the node (its public surface): :attr:`world`, :attr:`params`,
    :attr:`paused`, :attr:`detail`, :attr:`recorder`, :attr:`foxglove`, :attr:`command_inputs`, :meth:`reset`,
    :meth:`world_edited`, :meth:`report_rejection`, :meth:`emit_event`, and rclpy's own ``Node`` methods.
    """

    def __init__(self, *, parameter_overrides=None, node_name: str = "cgp_sim", loaded_scene=None):
        """``loaded_scene``: ``(value, Scene)``, the ``scene`` parameter's value as the caller already loaded it
        (``cgp-sim`` loads a scene named on its command line before the kernels' compile, to refuse a bad one at
        once); used when the parameter still has that value, so a big mesh's BVH is not built twice."""
        super().__init__(node_name, parameter_overrides=parameter_overrides)
        self._loaded_scene = loaded_scene
        #: the parameters' values by name (checked; updated by the parameter callback)
        self.params = read_parameters(self, self._parameter_overrides)
        #: the TF frame ids it writes and reads (parameter `frame_prefix`)
        self.frames = itf.Frames(self.params["frame_prefix"])
        self._describe_use_sim_time()
        #: the bag directory (resolved and checked once, before anything is built), or None: no recording
        self.bag_path = self._bag_path()
        self.world = self._load_world()
        self.paused = bool(self.params["start_paused"])
        #: set when `duration` is reached; the main loop then shuts the node down
        self.finished = False
        #: what is drawn and recorded at what rate (cgp_sim_ros/drawing/detail.py); set by _plan_detail
        self.detail: lod.DetailPlan | None = None
        #: the recording (parameter `bag`) and the live view (parameter `foxglove`), or None
        self.recorder = None
        self.foxglove = None
        #: the command subscriptions' and the publishers' QoS events' own waiting thread (ros/inbox.py)
        self.inbox = CommandInbox(self)
        try:
            self.outputs = TickPublisher(self)
            self.commands = CommandInputs(self)
            self._make_services()
            # Per body / per flock endpoints (odometry, wrench commands, flock poses): made here and again after
            # every spawn, delete or reset (see _sync_entities).
            self._synced_version = None
            self._sync_entities()
            # ROS 2's simulation_interfaces services and action (cgp_sim_ros.ros.sim_services)
            self.sim = SimulationInterfaces(self)
            if self.params["foxglove"]:
                self._start_foxglove()  # after the per-entity endpoints exist: it makes a channel for each
            self._plan_detail()
            if self.bag_path is not None:
                self._start_recording()
            self.emit_event(self.detail.event())  # after the recorder: the plan is the bag's first event
            self._start_timers()
            self.add_on_set_parameters_callback(self._on_set_parameters)
            self._log_start()
            self._prepare_process()
        except BaseException:
            self.inbox.close()  # a refused start leaves no thread running
            raise

    # ---- set-up (in the order __init__ runs them) -------------------------------------------------------

    def _bag_path(self) -> Path | None:
        if not self.params["bag"]:
            return None
        from .recorder import bag_directory  # the MCAP writer is imported only when recording

        return bag_directory(self.params["bag"])

    def _load_world(self) -> World:
        seed = self.params["seed"]
        scene = self.params["scene"]
        if self._loaded_scene is not None and self._loaded_scene[0] == scene:
            scene = self._loaded_scene[1]
        self._loaded_scene = None  # (not kept: a reset rebuilds from the world's own scene)
        try:
            return World.from_scene(scene, dt=1.0 / self.params["rate_hz"],
                                    substeps=self.params["substeps"] or None, seed=None if seed < 0 else seed)
        except SceneError as exc:
            raise ConfigError(f"scene: {exc}") from None

    def _make_services(self) -> None:
        self.create_service(Trigger, itf.SERVICE_RESET, self._on_reset)
        self.create_service(SetBool, itf.SERVICE_PAUSE, self._on_pause)
        self.create_service(Trigger, itf.SERVICE_STEP, self._on_step)
        self.create_service(Trigger, itf.SERVICE_CLEAR_WRENCHES, self._on_clear_wrenches)

    def _start_foxglove(self) -> None:
        from .foxglove_server import FoxgloveServer, FoxgloveServerError  # the SDK only with foxglove:=true

        try:
            self.foxglove = FoxgloveServer(self, host=self.params["foxglove_host"], port=self.params["foxglove_port"])
        except FoxgloveServerError as exc:
            raise ConfigError(f"foxglove: {exc}") from None

    def _start_recording(self) -> None:
        from ..wire.bag import BagExistsError
        from .recorder import Recorder

        try:
            self.recorder = Recorder(self, self.bag_path,
                                     max_bytes=self.params["bag_max_size"],
                                     max_duration_s=self.params["bag_max_duration"],
                                     custom_data=self._detail_custom_data())
        except BagExistsError as exc:  # created between the check in __init__ and now
            raise ConfigError(f"bag: {exc}") from None

    def _describe_use_sim_time(self) -> None:
        """rclpy's own ``use_sim_time``, described (:data:`cgp_sim_ros.interface.USE_SIM_TIME`): this node is
        the clock; with ``use_sim_time`` true its ROS clock follows the /clock it publishes, and its stepping,
        paced by the wall clock (:meth:`_start_timers`), goes on as before — Gazebo's behaviour."""
        self.set_descriptor("use_sim_time", ParameterDescriptor(
            name="use_sim_time", type=ParameterType.PARAMETER_BOOL, description=itf.USE_SIM_TIME.description))
        if self.get_parameter("use_sim_time").value:
            self.get_logger().info(itf.USE_SIM_TIME_NOTE)

    def _start_timers(self) -> None:
        #: the rate check: a window opens at the first tick after start-up, a pause or a change of rate
        self._rate = RateCheck(self.get_logger().warn)
        #: the clock the node's timers run on: steady wall time, whatever use_sim_time says.  This node
        #: publishes /clock; timers on its ROS clock would, with use_sim_time true, wait for a /clock that
        #: only their own ticks publish, and never fire (issue 27, finding 9)
        self._wall_clock = Clock(clock_type=ClockType.STEADY_TIME)
        self._timer = self.create_timer(self._timer_period(), self._on_timer, clock=self._wall_clock)
        #: batch runs (realtime:=false) show their progress: one updating line on a terminal, log lines otherwise
        self._progress = None if self.params["realtime"] else BatchReport(self.params["duration"],
                                                                          self.get_logger().info)
        # Reports on their own wall-clock timer, so rejected commands are summarized while paused too.
        self._report_timer = self.create_timer(itf.REPORT_PERIOD_S, self._report, clock=self._wall_clock)
        self._world_reports = WorldReports(self.get_logger(), self.emit_event)

    def _timer_period(self) -> float:
        # realtime=false: a zero-period timer is always ready, so the executor runs ticks back to back while
        # still serving subscriptions and services in between.
        return 1.0 / self.params["rate_hz"] if self.params["realtime"] else 0.0

    def _log_start(self) -> None:
        world = self.world
        counts = f"{world.body_model.count} bodies, " + ", ".join(
            f"flock {f.params.name} ({len(f.positions)} boids)" for f in world.flocks) if world.flocks \
            else f"{world.body_model.count} bodies"
        self.get_logger().info(
            f"scene {world.scene.source}: {counts}; {self.params['rate_hz']:g} Hz × {world.substeps} "
            f"substeps, integrator {world.scene.world.integrator}, "
            f"{'real time' if self.params['realtime'] else 'as fast as possible'}"
            + ("" if self.recorder is None else f", recording to {self.recorder.directory}"
               if self.recorder.recording else f", NOT recording (the bag {str(self.bag_path)!r} cannot be "
               "written: see the error above)"))
        self.get_logger().info("level of detail: " + " ".join(self.detail.lines))

    def _prepare_process(self) -> None:
        """The last step of the set-up: the process tuned for the tick (cgp_sim_ros/ros/process.py)."""
        process.load_kernels(self.world, self.outputs.build_throwaway, self.get_logger().debug)
        #: issue 25's kernels, loaded before the first spawned hull or mesh is added (process.ConvexKernels)
        self.convex_kernels = process.ConvexKernels(self.world)
        process.freeze_startup_objects()
        process.share_the_gil_finely()
        #: where the threads run (pin_threads); made here, on the thread that ticks
        self.threads = process.ThreadPinning(self.get_logger().info)
        self._place_threads()

    # ---- the public surface (what sim_services, foxglove_server and the tests use) ---------------------

    @property
    def command_inputs(self) -> dict[str, tuple[type, object]]:
        """Every command input: topic -> (message type, handler of its serialized bytes), for other
        transports (the Foxglove live view)."""
        return self.commands.inputs

    def reset(self, *, state: bool = True, spawned: bool = True) -> None:
        """Reset the world (:meth:`cgp_core.world.World.reset`: ``state``, ``spawned``; time keeps running),
        drop the pending commands with the state, redraw every marker (a DELETEALL first) and make everything
        follow (:meth:`world_edited`).  ``~/reset``, ``reset_simulation`` and ``set_simulation_state``
        STOPPED."""
        self.world.reset(state=state, spawned=spawned)
        if state:
            self.commands.clear_pending()
            self.commands.clear_joint_commands()
        self.outputs.redraw_all_markers()
        self.world_edited()

    def world_edited(self) -> None:
        """After any edit of the world (spawn, delete, reset, a new pose): the per-body and per-flock endpoints
        follow if its entities changed (:meth:`_sync_entities`), ``/tf_static`` and ``~/static_markers`` are sent
        again if its fixed bodies / static meshes did."""
        self._sync_entities()
        self.outputs.publish_static_tf()
        self.outputs.publish_static_markers()
        self.outputs.publish_robot_descriptions()

    def add_spawned(self, prepared, drawings=()) -> None:
        """Add an entity the spawn worker prepared (:class:`cgp_core.world.PreparedSpawn`, between two ticks:
        :meth:`cgp_core.world.World.add_spawned`, which checks the name and the limits again) with its shapes'
        drawings (``(shape, drawing)`` pairs, :mod:`cgp_sim_ros.drawing.bodies`), then make everything follow
        (:meth:`world_edited`).  Raises :class:`cgp_core.editing.EditError` (nothing changed)."""
        self.outputs.drawings.add(drawings)
        for _, drawing in drawings:
            if getattr(drawing, "problem", ""):  # a robot visual that is not drawn
                self.outputs.report_visual_problem(drawing)
        self.world.add_spawned(prepared)
        self.world_edited()

    def add_spawned_all(self, batch, drawings=()) -> None:
        """:meth:`add_spawned` for ``spawn_entities``' batch: all or none
        (:meth:`cgp_core.world.World.add_spawned_all`); raises :class:`cgp_core.editing.EditError` naming the
        entry, nothing changed."""
        self.outputs.drawings.add(drawings)
        self.world.add_spawned_all(batch)
        self.world_edited()

    def load_world(self, new=None, drawings=()) -> None:
        """Put another scene into the running world between two ticks (``load_world``; ``new`` the world built from
        it, :meth:`cgp_core.world.World.prepare_load` (:func:`process.build_world`), None for ``unload_world``'s
        empty world): :meth:`cgp_core.world.World.adopt` (time keeps running), the pending commands dropped with
        the old entities, every marker redrawn, the per-entity endpoints following (:meth:`world_edited`:
        publishers of the new entities made, of the gone ones destroyed)."""
        if new is None:
            self.world.unload()
        else:
            self.world.adopt(new)
        self.commands.clear_pending()
        self.commands.clear_joint_commands()
        self.outputs.scene_changed(drawings)
        self.world_edited()
        self._place_threads()

    def report_rejection(self, source: str, error, count: int = 1) -> None:
        """Count ``count`` rejected commands from ``source`` (a ``cgp_core.wrenches.WrenchError`` says which
        field and why): logged at once the first time, then summarized every REPORT_PERIOD_S."""
        self.commands.reject(source, error, count)

    def emit_event(self, payload: dict) -> None:
        """One line on ``~/events`` (published and recorded): the audit trail of what was done to the world."""
        self.outputs.event(payload)

    # ---- the world's entities ---------------------------------------------------------------------------

    def _sync_entities(self) -> None:
        """Make everything per body and per flock follow the world's current bodies and flocks (after start-up,
        a spawn, a delete or a reset; a no-op when ``world.model_version`` did not change):

        - ``~/bodies/<body>/odom`` publishers, ``~/bodies/<body>/wrench`` subscriptions (movable bodies),
          ``~/flocks/<flock>/poses`` and ``~/flocks/<flock>/stats`` publishers, ``~/robots/<robot>/joint_states``
          and ``robot_description`` publishers and ``joint_commands`` subscriptions: created for new entities,
          destroyed for gone ones, kept for the others (subscribers stay matched);
        - the new topics are added to the recording (new channels mid-recording, counted in metadata.yaml) and
          to the Foxglove live view, if on (new channels; the command inputs follow ``command_inputs``);
        - the per-tick serializers (:class:`TickMessages`, TF) are rebuilt for the new body set;
        - pending wrench commands follow their body (index), those on deleted bodies are dropped;
        - the markers of gone entities are deleted (a MarkerArray of DELETE actions, published at once) and
          ``/tf_static`` is sent again if the fixed bodies changed."""
        world = self.world
        if world.model_version == self._synced_version:
            return
        names = list(world.body_model.names)
        movable = {n for n, fixed in zip(names, world.body_model.fixed) if not fixed}
        added = self.outputs.follow_entities()
        added += self.commands.follow_bodies(names, movable)
        added += self.commands.follow_robots(robot_names(world))
        if self.recorder is not None and added:
            self.recorder.add_endpoints(added)
        if self.foxglove is not None:
            self.foxglove.follow_endpoints(added)
        self.outputs.rebuild()
        if self.detail is not None:  # after start-up: a flock spawned or deleted may change the plan (logged if so)
            self._replan_detail()
        self.outputs.tf.rebuild()
        self.outputs.retire_markers()
        if self._synced_version is not None:
            self.outputs.publish_static_tf()
        self._synced_version = world.model_version

    # ---- level of detail --------------------------------------------------------------------------------

    def _plan_detail(self) -> None:
        """(Re)make the level-of-detail plan from the flocks and the parameters (cgp_sim_ros/drawing/detail.py)."""
        self.detail = lod.plan([f.params for f in self.world.flocks], self.params["rate_hz"],
                               fish_detail=self.params["fish_detail"], markers_every=self.params["markers_every"],
                               flock_poses_every=self.params["bag_flock_poses_every"],
                               body_bytes=self.outputs.messages.body_bytes(),
                               body_set_bytes=self.outputs.messages.body_set_bytes())
        self.outputs.set_plan(self.detail)

    def _replan_detail(self) -> None:
        """A parameter the level of detail depends on changed: new plan, logged, on ~/events and in the bag
        (whose ``custom_data`` also holds the rate the plan is for)."""
        before = self.detail
        self._plan_detail()
        if before.same_choices(self.detail):
            return
        self.get_logger().info("level of detail changed: " + " ".join(self.detail.lines))
        self.outputs.retire_markers()  # fewer parts: the flock's last ones are no longer drawn
        self.outputs.publish_static_markers()  # the bodies' set in the new hull detail (if it changed)
        if self.recorder is not None:
            self.recorder.set_custom_data(self._detail_custom_data())
        self.emit_event(self.detail.event())

    def _detail_custom_data(self) -> dict:
        return self.detail.custom_data({f.params.name: pub.topic_name for f, pub in
                                        zip(self.world.flocks, self.outputs.pub_flock_poses)},
                                       self.outputs.pub_markers.topic_name)

    def _place_threads(self) -> None:
        self.threads.update(self.world.flocks, self.params["pin_threads"])

    # ---- the tick -----------------------------------------------------------------------------------------

    def _on_timer(self) -> None:
        if self.finished:
            return
        if self.sim.quit_due():
            self.finished = True
            return
        if self.paused:
            # a stepping request (~/step_simulation, ~/simulate_steps) ticks a paused world at the timer's pace
            if self.sim.stepping:
                self.tick()
                self.sim.stepped()
            return
        self.tick()

    def tick(self) -> None:
        """One simulation tick: commands in, step, everything out."""
        start = time.perf_counter()
        if self.recorder is not None and self.params["realtime"]:
            # the bag writer works between real-time ticks, not in them (back to back there is no "between":
            # it works beside the ticks)
            self.recorder.begin_tick()
        self.commands.apply_pending(self.world)
        self.outputs.prepare_tick()
        self.world.step()
        for event in self.world.take_events():
            self._world_reports.add(event)
        self.outputs.publish_tick()
        if self.recorder is not None:
            self.recorder.end_tick()  # the bag writer works while this thread waits for the next tick
        self._rate.ticked(time.perf_counter() - start)
        if self._rate.window_closed(rate_hz=self.params["rate_hz"], realtime=self.params["realtime"],
                                    paused=self.paused, dt=self.world.dt):
            self._place_threads()
        if self._progress is not None and self._progress.due():
            self._show_progress()
        duration = self.params["duration"]
        if duration > 0.0 and self.world.time_ns >= round(duration * 1e9) and not self.finished:
            self.finished = True
            if self._progress is not None:
                self._show_progress(final=True)
            self.get_logger().info(f"duration {duration:g} s of simulated time reached after {self.world.ticks} "
                                   "ticks; shutting down")

    def _show_progress(self, final: bool = False) -> None:
        bag_bytes = self.recorder.size_bytes() if self.recorder is not None else None
        self._progress.show(self.world.time, self.world.ticks, bag_bytes, final=final)

    def _report(self) -> None:
        """Every REPORT_PERIOD_S of wall time: rejected / dropped commands, recording errors."""
        self.commands.report()
        self._world_reports.report()
        capped = self.outputs.report_contacts_capped()
        if capped is not None:
            self._world_reports.add_text("warn", capped)
        if self.recorder is not None:
            self.recorder.report_errors()

    # ---- services ----------------------------------------------------------------------------------------

    def _on_reset(self, request, response):
        self.reset()
        self.emit_event({"event": "service", "name": "reset"})
        response.success = True
        response.message = f"reset to the initial state of {self.world.scene.source} at t = {self.world.time:.9f} s"
        return response

    def _on_pause(self, request, response):
        self.sim.set_paused(bool(request.data))
        self._rate.restart()  # time spent paused is not "falling behind"
        self.emit_event({"event": "service", "name": "pause", "data": self.paused})
        response.success = True
        response.message = f"{'paused' if self.paused else 'running'} at t = {self.world.time:.9f} s"
        return response

    def _on_step(self, request, response):
        self.emit_event({"event": "service", "name": "step"})
        if not self.paused:
            response.success = False
            response.message = "not paused: call ~/pause with data: true first"
            return response
        if self.sim.stepping:
            response.success = False
            response.message = "a stepping request (~/step_simulation or ~/simulate_steps) is running"
            return response
        self.sim.stopped = False
        self.commands.take_arrived()  # what was sent before the request is applied by this step
        self.tick()
        response.success = True
        response.message = f"stepped to t = {self.world.time:.9f} s (tick {self.world.ticks})"
        return response

    def _on_clear_wrenches(self, request, response):
        active = self.world.wrenches.active
        self.world.clear_wrenches()
        pending = self.commands.clear_pending()
        self.emit_event({"event": "service", "name": "clear_wrenches", "cleared": active + pending})
        response.success = True
        response.message = f"cleared {active} active wrench(es) and {pending} pending command(s)"
        return response

    # ---- parameters at run time --------------------------------------------------------------------------

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        problem = refusal(parameters)
        if problem:
            return SetParametersResult(successful=False, reason=problem)
        for param in parameters:
            if param.name == "use_sim_time" and param.value:
                self.get_logger().info(itf.USE_SIM_TIME_NOTE)
            if param.name not in itf.PARAMETER_BY_NAME:
                continue
            self.params[param.name] = coerce(itf.PARAMETER_BY_NAME[param.name], param.value)
            if param.name == "rate_hz":
                self.world.set_dt(1.0 / param.value)
            if param.name in ("rate_hz", "realtime"):
                self._timer.cancel()
                self.destroy_timer(self._timer)
                self._timer = self.create_timer(self._timer_period(), self._on_timer, clock=self._wall_clock)
                self._rate.restart()  # the rate check starts over at the new rate
        if any(param.name in ("rate_hz", "markers_every", "fish_detail") for param in parameters):
            self._replan_detail()
        if any(param.name == "pin_threads" for param in parameters):
            self._place_threads()
        return SetParametersResult(successful=True)

    # ---- shutdown ----------------------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the command inbox's thread and the Foxglove server, finish the recording (summary, metadata.yaml)
        and the progress line; safe to call twice."""
        if hasattr(self, "inbox"):
            self.inbox.close()
        if self.foxglove is not None:
            self.foxglove.close()
        if self._progress is not None:
            self._progress.finish()
        if self.recorder is not None:
            self.recorder.close()

    def destroy_node(self) -> None:
        """rclpy's ``destroy_node`` plus what it leaves behind: the ``simulate_steps`` action server.  rclpy
        destroys a node's publishers, subscriptions, services, timers and guard conditions, but not its action
        servers, and a live action server keeps the rcl node, and with it the process's DDS participant, alive
        until the process exits.  Fast DDS then deletes that participant from a static destructor while its
        threads still handle other participants leaving — seen as a node hanging at exit at full CPU, or
        aborting with "malloc_consolidate(): unaligned fastbin chunk detected", when several nodes on one
        domain stop at once."""
        if hasattr(self, "inbox"):
            self.inbox.close()  # its thread waits on subscriptions rclpy is about to destroy
        self.sim.close()
        if hasattr(self, "threads"):
            self.threads.release()
        super().destroy_node()


class WorldReports:
    """The world's own events (a numerical blow-up contained, ...: :class:`cgp_core.world.WorldEvent`), logged and
    put on ``~/events`` like the rejected commands are: the first of each text at once, repeats counted and
    summarized every REPORT_PERIOD_S (a body blowing up every tick is one line every two seconds, not 60)."""

    def __init__(self, logger, emit_event):
        self._logger = logger
        self._emit = emit_event
        self._seen: set[tuple[str, str]] = set()
        self._repeats: dict[tuple[str, str], int] = {}

    def add_text(self, level: str, text: str) -> None:
        """A report of the node's own (not the world's), logged and put on ``~/events`` the same way."""
        self.add(WorldEvent(0.0, level, text))

    def add(self, event) -> None:
        key = (event.level, event.text)
        if key in self._seen:
            self._repeats[key] = self._repeats.get(key, 0) + 1
            return
        if len(self._seen) > 1000:  # bounded: many different texts start over
            self._seen.clear()
        self._seen.add(key)
        self._log(event.level, event.text)
        self._emit({"event": "world", "level": event.level, "text": event.text})

    def report(self) -> None:
        for (level, text), count in self._repeats.items():
            self._log(level, f"{text} (again {count} times in the last {itf.REPORT_PERIOD_S:g} s)")
            self._emit({"event": "world", "level": level, "text": text, "repeated": count})
        # a text that went quiet is logged at once when it comes back; one that repeats stays summarized
        self._seen = {key for key in self._seen if key in self._repeats}
        self._repeats.clear()

    def _log(self, level: str, text: str) -> None:
        # one call per severity: rclpy's logger refuses a call site whose severity changes between calls
        # ("Logger severity cannot be changed between calls": an info after a warn from one line stopped the node)
        if level == "error":
            self._logger.error(text)
        elif level == "info":  # e.g. a static mesh's BVH built (issue 25)
            self._logger.info(text)
        else:
            self._logger.warn(text)

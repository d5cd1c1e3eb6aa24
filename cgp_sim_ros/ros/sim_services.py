"""ROS 2's ``simulation_interfaces`` (Jazzy 1.5.1) on the cgp_sim node: the services and the action a tool
written against the standard calls, on Gazebo, Isaac Sim, O3DE and here alike.

Every service name is relative to the node (``/cgp_sim/spawn_entity`` by default), as ros_gz_sim has them;
:mod:`cgp_sim_ros.interface` lists them.  The world edits go to :class:`cgp_core.world.World` (spawn, delete,
set_body_state / move_flock, entity_state, entity_names) and the node's own reset (:meth:`SimNode.reset`); after
an edit the node makes its per-body endpoints follow (:meth:`SimNode.world_edited`).  Rules kept by every handler:

- The reply carries ``simulation_interfaces/msg/Result``: ``RESULT_OK`` or the most specific code the service
  defines (``SpawnEntity.Response.NAME_NOT_UNIQUE``, ...), and an ``error_message`` naming what was wrong.  A
  refused request changes nothing.
- Every call is a line on ``~/events`` (and so in the bag): service, request summary, result code and message.
- Nothing blocks the executor for long: ``step_simulation`` and the ``simulate_steps`` action are coroutines
  that wait for the node's timer to tick the paused world ``steps`` times (at ``rate_hz``, or back to back
  with ``realtime: false``) and reply when the last tick is done.  ``spawn_entity`` is a coroutine too: reading the
  ``uri`` (a regular file only, size-capped: :mod:`cgp_core.user_input`), parsing the YAML (bounded in bytes,
  depth and nodes), validating it, building the entity (hulls, a static mesh's BVH, a big flock's initial state)
  and drawing it run in the spawn worker *process* (:mod:`cgp_sim_ros.workers`, the job
  :func:`cgp_sim_ros.spawning.prepare`) while the node ticks — another interpreter, so not even the GIL is
  shared (issue 38); a job that takes longer than the ``spawn_timeout`` parameter is ended and refused, and the
  requests behind it go on.  The entity is added between two ticks (issue 27: one request must never stop the
  world).  User regexes are matched in linear time (:func:`cgp_core.editing.name_filter`).

Simulation states (``SimulationState``): PLAYING (ticking), PAUSED (time stopped), STOPPED (paused and reset
to the scene as loaded; the state a paused world is in until it ticks or is set PAUSED / PLAYING), QUITTING
(the reply is sent, then the node shuts down cleanly: the bag is finished).  Time never goes backwards: a
reset or STOPPED keeps the clock running (no ``SCOPE_TIME``), so TF buffers and bags stay consistent.
"""

from __future__ import annotations

import inspect
import time
import traceback
from dataclasses import dataclass, field

import numpy as np
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.task import Future
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.msg import Bounds, EntityState, Result, SimulationState, SimulatorFeatures
from simulation_interfaces.srv import (
    DeleteEntity,
    GetEntities,
    GetEntitiesStates,
    GetEntityState,
    GetSimulationState,
    GetSimulatorFeatures,
    ResetSimulation,
    SetEntityState,
    SetSimulationState,
    SpawnEntity,
    StepSimulation,
)

from cgp_core.editing import WORLD_FRAMES, EditError
from cgp_core.limits import MAX_YAML_BYTES

from .. import interface as itf
from ..spawning import SPAWN_FORMATS, Refusal, SpawnRequest, brief, prepare, warm_up
from ..workers import JobFailed, WorkerProcess

OK = Result.RESULT_OK
NOT_FOUND = Result.RESULT_NOT_FOUND
UNSUPPORTED = Result.RESULT_FEATURE_UNSUPPORTED
INCORRECT_STATE = Result.RESULT_INCORRECT_STATE
FAILED = Result.RESULT_OPERATION_FAILED

#: spawn requests waiting for the spawn worker (one is prepared at a time); more are refused as busy
MAX_WAITING_SPAWNS = 8

#: after set_simulation_state QUITTING, the node answers for this long (wall seconds) before shutting down,
#: so the reply reaches the caller before the service goes away
QUIT_LINGER_S = 0.3

#: what GetSimulatorFeatures reports (SimulatorFeatures constants)
FEATURES = (
    SimulatorFeatures.SPAWNING, SimulatorFeatures.DELETING, SimulatorFeatures.SPAWNING_RESOURCE_STRING,
    SimulatorFeatures.ENTITY_STATE_GETTING, SimulatorFeatures.ENTITY_STATE_SETTING,
    SimulatorFeatures.SIMULATION_RESET, SimulatorFeatures.SIMULATION_RESET_STATE,
    SimulatorFeatures.SIMULATION_RESET_SPAWNED, SimulatorFeatures.SIMULATION_STATE_GETTING,
    SimulatorFeatures.SIMULATION_STATE_SETTING, SimulatorFeatures.SIMULATION_STATE_PAUSE,
    SimulatorFeatures.STEP_SIMULATION_SINGLE, SimulatorFeatures.STEP_SIMULATION_MULTIPLE,
    SimulatorFeatures.STEP_SIMULATION_ACTION,
)
CUSTOM_INFO = (
    "cgp_sim: spawn_entity takes YAML (resource_string, or a .yaml file as uri: a path or file:// URI) with "
    "exactly one key, body, flock or robot, whose value is a scene-file entry without name (the request's) and, for a "
    "body, without position/orientation (initial_pose; for a flock initial_pose.position is the spawn centre); "
    "a mesh: in it is read from the .yaml file's directory (else the built-in meshes) or a file:// URI. An .stl / "
    ".obj file as uri spawns a convex body, the hull of the mesh (density 1000 kg/m3). A robot: a .urdf / .xacro "
    "file as uri, URDF XML as resource_string (starting with '<'; no DOCTYPE/entities, never xacro), or YAML "
    "{robot: <a scene's robots entry without name/position/orientation; urdf_xml: URDF text instead of urdf>}; "
    "initial_pose places its root link; it is an entity (its links are bodies <robot>/<link>), its state is the "
    "root link frame's pose and twist, set only for a floating base. "
    "Entity states: a body's COM pose, twist in world axes, last tick's acceleration; a flock's centroid and "
    "mean velocity (set moves it rigidly). Reset scopes STATE, SPAWNED, ALL; time keeps running (no "
    "SCOPE_TIME). get_entities filters: POSIX ERE on names, TYPE_SPHERE bounds. See docs/simulation-interfaces.md."
)

_STATE_NAMES = {SimulationState.STATE_STOPPED: "STOPPED", SimulationState.STATE_PLAYING: "PLAYING",
                SimulationState.STATE_PAUSED: "PAUSED", SimulationState.STATE_QUITTING: "QUITTING",
                SimulationState.STATE_NO_WORLD: "NO_WORLD", SimulationState.STATE_LOADING_WORLD: "LOADING_WORLD"}
_SCOPE_TIME, _SCOPE_STATE, _SCOPE_SPAWNED = (ResetSimulation.Request.SCOPE_TIME, ResetSimulation.Request.SCOPE_STATE,
                                             ResetSimulation.Request.SCOPE_SPAWNED)
_SCOPE_ALL = (ResetSimulation.Request.SCOPE_DEFAULT, ResetSimulation.Request.SCOPE_ALL)


def _code_names(*interfaces) -> dict[int, str]:
    names = {Result.RESULT_FEATURE_UNSUPPORTED: "FEATURE_UNSUPPORTED", OK: "OK", NOT_FOUND: "NOT_FOUND",
             INCORRECT_STATE: "INCORRECT_STATE", FAILED: "OPERATION_FAILED"}
    for interface in interfaces:
        names.update({value: name for name, value in vars(interface).items()
                      if name.isupper() and isinstance(value, int) and value > 100})
    return names


@dataclass
class _SteppingJob:
    """A request to tick the paused world ``total`` times (the service's or the action's)."""

    total: int
    future: Future = field(default_factory=Future)
    done: int = 0
    on_tick: object = None  # callable(done, total) -> None: the action's feedback
    cancel_requested: object = None  # callable() -> bool: the action's cancel

    def finish(self, code: int, message: str, outcome: str) -> None:
        if not self.future.done():
            self.future.set_result((code, message, outcome))


class SimulationInterfaces:
    """The services and the action, on ``node`` (a :class:`cgp_sim_ros.ros.node.SimNode`; this class uses its
    public surface: ``world``, ``paused``, ``reset``, ``world_edited``, ``emit_event``)."""

    def __init__(self, node):
        self.node = node
        #: paused and reset since (STATE_STOPPED); cleared by a tick, PAUSED or PLAYING
        self.stopped = False
        self.quitting = False
        self._quit_at: float | None = None
        self._job: _SteppingJob | None = None
        #: the spawn worker process: reads, parses, validates, builds and draws spawned entities off the tick's
        #: thread and GIL.  Started by the first request (a second or two, not counted in its spawn_timeout):
        #: a node nobody spawns into never pays for it (imports, kernels loaded or, after an install, compiled)
        self.spawn_worker = WorkerProcess("cgp-sim-spawn", warm_up=warm_up)
        self._spawn_running = False
        self._spawns_waiting = 0
        services = (
            (GetSimulatorFeatures, itf.SERVICE_GET_SIMULATOR_FEATURES, self._get_simulator_features),
            (SpawnEntity, itf.SERVICE_SPAWN_ENTITY, self._spawn_entity),
            (DeleteEntity, itf.SERVICE_DELETE_ENTITY, self._delete_entity),
            (GetEntities, itf.SERVICE_GET_ENTITIES, self._get_entities),
            (GetEntitiesStates, itf.SERVICE_GET_ENTITIES_STATES, self._get_entities_states),
            (GetEntityState, itf.SERVICE_GET_ENTITY_STATE, self._get_entity_state),
            (SetEntityState, itf.SERVICE_SET_ENTITY_STATE, self._set_entity_state),
            (ResetSimulation, itf.SERVICE_RESET_SIMULATION, self._reset_simulation),
            (GetSimulationState, itf.SERVICE_GET_SIMULATION_STATE, self._get_simulation_state),
            (SetSimulationState, itf.SERVICE_SET_SIMULATION_STATE, self._set_simulation_state),
            (StepSimulation, itf.SERVICE_STEP_SIMULATION, self._step_simulation),
        )
        # The stepping coroutines wait for the node's timer, which is in the node's default (mutually exclusive)
        # callback group: a coroutine in that group would hold it until it returns, and the timer would never
        # tick.  Their own reentrant group lets the timer run meanwhile (still one thread: no locks needed), and
        # lets a second stepping request be answered (refused) at once instead of queueing.
        stepping_group = ReentrantCallbackGroup()
        # spawn_entity is a coroutine too (it waits for the spawn worker)
        self.services = [node.create_service(srv_type, name, self._guarded(name, callback),
                                             callback_group=stepping_group if srv_type in (StepSimulation, SpawnEntity)
                                             else None)
                         for srv_type, name, callback in services]
        self.action_server = ActionServer(node, SimulateSteps, itf.ACTION_SIMULATE_STEPS, self._simulate_steps,
                                          callback_group=stepping_group,
                                          goal_callback=lambda goal: GoalResponse.ACCEPT,
                                          cancel_callback=lambda goal_handle: CancelResponse.ACCEPT)

    def close(self) -> None:
        """Destroy the action server (:meth:`SimNode.destroy_node` says why rclpy's ``destroy_node`` does not);
        the services go with the node.  Safe to call twice."""
        if self.action_server is not None:
            self.action_server.destroy()
            self.action_server = None
        self.spawn_worker.close()

    def _guarded(self, name: str, callback):
        """``callback`` that answers OPERATION_FAILED (and logs the traceback) instead of raising: a bug in one
        request must not take the simulation down (an exception in a callback ends rclpy's spin)."""
        service = name.removeprefix("~/")

        def failed(response, exc: Exception):
            self.node.get_logger().error(f"{service} failed: {exc!r}\n{traceback.format_exc()}")
            if hasattr(response, "result"):
                response.result = Result(result=FAILED, error_message=f"internal error: {exc!r}")
            self.node.emit_event({"event": "service", "name": service, "result": "OPERATION_FAILED",
                                  "message": f"internal error: {exc!r}"})
            return response

        if inspect.iscoroutinefunction(callback):
            async def guarded_async(request, response):
                try:
                    return await callback(request, response)
                except Exception as exc:  # noqa: BLE001 - see the docstring
                    return failed(response, exc)
            return guarded_async

        def guarded(request, response):
            try:
                return callback(request, response)
            except Exception as exc:  # noqa: BLE001 - see the docstring
                return failed(response, exc)
        return guarded

    # ---- simulation state -----------------------------------------------------------------------------

    @property
    def state(self) -> int:
        if self.quitting:
            return SimulationState.STATE_QUITTING
        if not self.node.paused:
            return SimulationState.STATE_PLAYING
        return SimulationState.STATE_STOPPED if self.stopped else SimulationState.STATE_PAUSED

    def set_paused(self, paused: bool) -> None:
        """Pause or play (``~/pause`` and ``set_simulation_state``).  Playing ends a running stepping request
        (it replies OPERATION_FAILED: the steps were not taken while paused)."""
        self.node.paused = paused
        if not paused:
            self.stopped = False
            self._abort_job("interrupted: the simulation was set playing")

    def quit_due(self) -> bool:
        """True once the node should shut down (QUITTING was requested and its reply had time to go out)."""
        return self._quit_at is not None and time.monotonic() >= self._quit_at

    @property
    def stepping(self) -> bool:
        return self._job is not None

    def stepped(self) -> None:
        """The node ticked the paused world for the running stepping request."""
        job = self._job
        job.done += 1
        self.stopped = False
        if job.on_tick is not None:
            job.on_tick(job.done, job.total)
        if job.done >= job.total:
            self._job = None
            job.finish(OK, "", "succeeded")
        elif job.cancel_requested is not None and job.cancel_requested():
            self._job = None
            job.finish(FAILED, f"canceled after {job.done} of {job.total} steps", "canceled")

    def _abort_job(self, reason: str) -> None:
        job, self._job = self._job, None
        if job is not None:
            job.finish(FAILED, f"{reason} after {job.done} of {job.total} steps", "aborted")

    def _start_job(self, steps: int, on_tick=None, cancel_requested=None) -> tuple[int, str] | _SteppingJob:
        """A stepping job, or the refusal (code, message)."""
        if self.quitting:
            return INCORRECT_STATE, "the simulator is quitting"
        if not self.node.paused:
            return FAILED, "the simulation is playing: steps are taken while paused (set_simulation_state " \
                           "STATE_PAUSED first)"
        if self._job is not None:
            return FAILED, f"another stepping request is running ({self._job.total - self._job.done} of " \
                           f"{self._job.total} steps left)"
        if steps < 1:
            return FAILED, f"steps must be at least 1, got {steps}"
        self._job = _SteppingJob(int(steps), on_tick=on_tick, cancel_requested=cancel_requested)
        self.stopped = False
        return self._job

    # ---- helpers ----------------------------------------------------------------------------------------

    def _reply(self, response, service: str, code: int, message: str = "", codes=(), **summary):
        """Fill ``response.result``, log the call on ~/events, return the response."""
        response.result = Result(result=code, error_message=message)
        self._event(service, code, message, codes, **summary)
        return response

    def _event(self, service: str, code: int, message: str, codes=(), **summary) -> None:
        payload = {"event": "service", "name": service, **summary, "result": _code_names(*codes).get(code, code)}
        if message:
            payload["message"] = message
        self.node.emit_event(payload)

    def _entity_state_msg(self, name: str) -> EntityState:
        state = self.node.world.entity_state(name)
        msg = EntityState()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(self.node.world.time_ns, 1_000_000_000)
        msg.header.frame_id = self.node.frames.world
        p, q = msg.pose.position, msg.pose.orientation
        p.x, p.y, p.z = map(float, state.position)
        q.x, q.y, q.z, q.w = map(float, state.orientation)
        for vector, values in ((msg.twist.linear, state.linear_velocity), (msg.twist.angular, state.angular_velocity),
                               (msg.acceleration.linear, state.linear_acceleration),
                               (msg.acceleration.angular, state.angular_acceleration)):
            vector.x, vector.y, vector.z = map(float, values)
        return msg

    def _filtered_names(self, filters) -> tuple[int, str, list[str]]:
        """Names passing ``simulation_interfaces/msg/EntityFilters``: the name regex and TYPE_SPHERE bounds are
        supported; categories and tags are not (FEATURE_UNSUPPORTED when given)."""
        world = self.node.world
        if filters.categories:
            return UNSUPPORTED, "filters.categories: entity categories are not supported", []
        if filters.tags.tags:
            return UNSUPPORTED, "filters.tags: entity tags are not supported", []
        try:
            names = world.entity_names(filters.filter)
        except ValueError as exc:
            return FAILED, f"filters.filter: {exc}", []
        bounds = filters.bounds
        if bounds.type == Bounds.TYPE_EMPTY:
            return OK, "", names
        if bounds.type != Bounds.TYPE_SPHERE:
            return UNSUPPORTED, f"filters.bounds.type {bounds.type}: only TYPE_SPHERE ({Bounds.TYPE_SPHERE}) " \
                                "bounds are supported", []
        if len(bounds.points) != 2:
            return FAILED, f"filters.bounds: TYPE_SPHERE needs 2 points (centre; radius in x), got " \
                           f"{len(bounds.points)}", []
        center = [bounds.points[0].x, bounds.points[0].y, bounds.points[0].z]
        radius = bounds.points[1].x
        if not (np.isfinite(center).all() and np.isfinite(radius) and radius >= 0.0):
            return FAILED, f"filters.bounds: the centre must be finite and the radius (points[1].x) finite and " \
                           f">= 0, got centre {center}, radius {radius}", []
        inside = set(world.entities_in_sphere(center, radius))
        return OK, "", [n for n in names if n in inside]

    # ---- services -----------------------------------------------------------------------------------------

    def _get_simulator_features(self, request, response):
        response.features.features = list(FEATURES)
        response.features.spawn_formats = list(SPAWN_FORMATS)
        response.features.custom_info = CUSTOM_INFO
        self.node.emit_event({"event": "service", "name": "get_simulator_features", "result": "OK"})
        return response

    async def _spawn_entity(self, request, response):
        code, message, name = await self._spawn(request)
        response.entity_name = name if code == OK else ""
        summary = {"entity": request.name, "uri": request.uri} if request.uri else {"entity": request.name}
        if code == OK:
            summary["entity_name"] = name
        return self._reply(response, "spawn_entity", code, message, (SpawnEntity.Response,), **summary)

    async def _spawn(self, request) -> tuple[int, str, str]:
        """The spawn: cheap checks here; reading, parsing, validating, building and drawing in the spawn worker
        process (:func:`cgp_sim_ros.spawning.prepare`, at most ``spawn_timeout`` seconds), so the tick never waits
        for them; then the entity is added here, between two ticks.  One spawn is prepared at a time; at most
        MAX_WAITING_SPAWNS wait."""
        R = SpawnEntity.Response
        if request.uri:
            source = request.uri
        elif request.resource_string:
            size = len(request.resource_string)
            if size > MAX_YAML_BYTES:  # refused before anything reads it (a character is at least one byte)
                return R.RESOURCE_PARSE_ERROR, (f"resource_string: {size} characters; at most {MAX_YAML_BYTES} "
                                                "bytes of YAML are parsed"), ""
            source = "resource_string"
        else:
            return R.NO_RESOURCE, ("uri and resource_string are both empty: give the entity as YAML (or a robot as "
                                   "URDF)"), ""
        if request.entity_namespace:
            return UNSUPPORTED, (f"entity_namespace {brief(request.entity_namespace)}: not supported; an entity's "
                                 "topics are the node's (~/bodies/<name>/...)"), ""
        frame = request.initial_pose.header.frame_id
        if self.node.frames.to_core(frame) not in WORLD_FRAMES:
            return R.INVALID_POSE, (f"initial_pose.header.frame_id {brief(frame)}: poses are given in "
                                    f"{self.node.frames.world!r} (or '')"), ""
        if not request.name and not request.allow_renaming:
            return R.NAME_INVALID, "name is empty (and allow_renaming is false)", ""
        if not request.allow_renaming:  # a name already taken is refused before anything is read
            try:
                self.node.world.check_new_name(request.name)
            except EditError as exc:
                return (R.NAME_NOT_UNIQUE if exc.kind == "name_taken" else R.NAME_INVALID), str(exc), ""
        if self._spawns_waiting >= MAX_WAITING_SPAWNS:
            return FAILED, f"busy: {self._spawns_waiting} spawn requests are waiting (at most " \
                           f"{MAX_WAITING_SPAWNS}); try again", ""
        self._spawns_waiting += 1
        try:
            while self._spawn_running:
                await _NextTurn()
            self._spawn_running = True
            try:
                pose = request.initial_pose.pose
                timeout = float(self.node.params["spawn_timeout"])
                job = self.spawn_worker.submit(prepare, SpawnRequest(
                    uri=request.uri, resource=request.resource_string if not request.uri else "", source=source,
                    name=request.name, allow_renaming=request.allow_renaming,
                    taken=frozenset(self.node.world.entity_names()),
                    position=(pose.position.x, pose.position.y, pose.position.z),
                    orientation=(pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w),
                    world=self.node.world.scene.world), timeout=timeout)
                while not job.done():
                    await _NextTurn()
                if self.quitting:
                    return INCORRECT_STATE, "the simulator is quitting", ""
                try:
                    outcome = job.result()
                except JobFailed as failure:
                    return FAILED, self._job_failure(failure, timeout), ""
                if isinstance(outcome, Refusal):
                    return _REFUSAL_CODES.get(outcome.kind, FAILED), outcome.message, ""
                loading = self.node.convex_kernels.before_adding(outcome.prepared)
                while loading is not None and not loading.done():
                    await _NextTurn()
                if self.quitting:
                    return INCORRECT_STATE, "the simulator is quitting", ""
                try:
                    self.node.add_spawned(outcome.prepared, outcome.drawings)
                except EditError as exc:
                    code = {"name_taken": R.NAME_NOT_UNIQUE, "name_invalid": R.NAME_INVALID,
                            "invalid_pose": R.INVALID_POSE}.get(exc.kind, FAILED)
                    return code, str(exc), ""
                prepared = outcome.prepared
            finally:
                self._spawn_running = False
        finally:
            self._spawns_waiting -= 1
        return OK, "", prepared.name

    def _job_failure(self, failure: JobFailed, timeout: float) -> str:
        """The refusal's message for a spawn job that gave no answer (and the log line, with the details)."""
        if failure.reason == "timeout":
            return (f"the spawn took longer than spawn_timeout ({timeout:g} s) and was stopped; nothing was added "
                    "(a smaller entity, or a larger spawn_timeout)")
        if failure.reason == "died":
            self.node.get_logger().error(f"spawn_entity: the spawn worker process {failure}")
            return f"the spawn worker process {failure}; nothing was added (the next request gets a new one)"
        if failure.reason == "closed":
            return "the simulator is shutting down"
        self.node.get_logger().error(f"spawn_entity failed in the spawn worker: {failure}\n{failure.details}")
        return f"internal error in the spawn worker: {failure}"

    def _delete_entity(self, request, response):
        try:
            kind = self.node.world.delete(request.entity)
        except EditError as exc:
            return self._reply(response, "delete_entity", NOT_FOUND, str(exc), entity=request.entity)
        self.node.world_edited()
        return self._reply(response, "delete_entity", OK, entity=request.entity, kind=kind)

    def _get_entities(self, request, response):
        code, message, names = self._filtered_names(request.filters)
        response.entities = names
        return self._reply(response, "get_entities", code, message, filter=request.filters.filter,
                           count=len(names))

    def _get_entities_states(self, request, response):
        code, message, names = self._filtered_names(request.filters)
        response.entities = names
        response.states = [self._entity_state_msg(n) for n in names]
        return self._reply(response, "get_entities_states", code, message, filter=request.filters.filter,
                           count=len(names))

    def _get_entity_state(self, request, response):
        if self.node.world.entity_kind(request.entity) is None:
            return self._reply(response, "get_entity_state", NOT_FOUND, _unknown(self.node.world, request.entity),
                               entity=request.entity)
        response.state = self._entity_state_msg(request.entity)
        return self._reply(response, "get_entity_state", OK, entity=request.entity)

    def _set_entity_state(self, request, response):
        code, message = self._set_state(request.entity, request.state)
        return self._reply(response, "set_entity_state", code, message, (SetEntityState.Response,),
                           entity=request.entity)

    def _set_state(self, name: str, state) -> tuple[int, str]:
        R = SetEntityState.Response
        world = self.node.world
        kind = world.entity_kind(name)
        if kind is None:
            return NOT_FOUND, _unknown(world, name)
        if self.node.frames.to_core(state.header.frame_id) not in WORLD_FRAMES:
            return R.INVALID_POSE, (f"state.header.frame_id {state.header.frame_id!r}: states are given in "
                                    f"{self.node.frames.world!r} (or '')")
        p, q = state.pose.position, state.pose.orientation
        position, orientation = (p.x, p.y, p.z), (q.x, q.y, q.z, q.w)
        linear, angular = _xyz(state.twist.linear), _xyz(state.twist.angular)
        accelerating = any(_xyz(state.acceleration.linear)) or any(_xyz(state.acceleration.angular))
        try:
            if kind == "flock":
                if any(linear) or any(angular) or accelerating:
                    return FAILED, f"{name} is a flock: its boids steer themselves; set its pose only (twist and " \
                                   "acceleration zero)"
                if not (abs(abs(q.w) - 1.0) < 1e-9 and q.x == q.y == q.z == 0.0):
                    return R.INVALID_POSE, f"{name} is a flock: it has no orientation of its own; give the " \
                                           "identity (0, 0, 0, 1)"
                world.move_flock(name, position)
            else:
                if kind == "body" and accelerating and world.body_model.fixed[world.body_model.names.index(name)]:
                    return FAILED, f"{name} is fixed: it takes a pose, not an acceleration"
                world.set_body_state(name, position, orientation, linear, angular)
        except EditError as exc:
            return (R.INVALID_POSE if exc.kind == "invalid_pose" else FAILED), str(exc)
        self.node.world_edited()  # a fixed body may have moved: /tf_static
        return OK, ""

    def _reset_simulation(self, request, response):
        scope = request.scope
        if scope in _SCOPE_ALL:
            state, spawned = True, True
        else:
            unknown = scope & ~(_SCOPE_TIME | _SCOPE_STATE | _SCOPE_SPAWNED)
            if scope & _SCOPE_TIME or unknown or not scope:
                reason = (f"scope {scope}: SCOPE_TIME is not supported (time never goes backwards here: TF buffers "
                          "and bags stay consistent); SCOPE_ALL resets everything else" if scope & _SCOPE_TIME
                          else f"scope {scope}: unknown scope bits {unknown}")
                return self._reply(response, "reset_simulation", UNSUPPORTED, reason, scope=scope)
            state, spawned = bool(scope & _SCOPE_STATE), bool(scope & _SCOPE_SPAWNED)
        self.node.reset(state=state, spawned=spawned)
        return self._reply(response, "reset_simulation", OK, scope=scope)

    def _get_simulation_state(self, request, response):
        response.state.state = self.state
        return self._reply(response, "get_simulation_state", OK, state=_STATE_NAMES[self.state])

    def _set_simulation_state(self, request, response):
        target = request.state.state
        code, message = self._transition(target)
        return self._reply(response, "set_simulation_state", code, message, (SetSimulationState.Response,),
                           state=_STATE_NAMES.get(target, target))

    def _transition(self, target: int) -> tuple[int, str]:
        R = SetSimulationState.Response
        S = SimulationState
        current = self.state
        if target in (S.STATE_NO_WORLD, S.STATE_LOADING_WORLD):
            return UNSUPPORTED, f"{_STATE_NAMES[target]}: loading and unloading worlds is not supported"
        if target not in (S.STATE_STOPPED, S.STATE_PLAYING, S.STATE_PAUSED, S.STATE_QUITTING):
            return R.INCORRECT_TRANSITION, f"unknown state {target} (valid: 0 STOPPED, 1 PLAYING, 2 PAUSED, " \
                                           "3 QUITTING)"
        if current == S.STATE_QUITTING:
            return R.INCORRECT_TRANSITION, "the simulator is quitting"
        if target == current:
            return R.ALREADY_IN_TARGET_STATE, f"already {_STATE_NAMES[current]}"
        if target == S.STATE_PLAYING:
            self.set_paused(False)
        elif target == S.STATE_PAUSED:
            self.node.paused = True
            self.stopped = False
        elif target == S.STATE_STOPPED:
            self._abort_job("interrupted: the simulation was stopped")
            self.node.paused = True
            self.node.reset()
            self.stopped = True
        else:  # QUITTING
            self._abort_job("interrupted: the simulator is quitting")
            self.node.paused = True
            self.quitting = True
            self._quit_at = time.monotonic() + QUIT_LINGER_S
            self.node.get_logger().info("set_simulation_state QUITTING: shutting down")
        return OK, ""

    async def _step_simulation(self, request, response):
        job = self._start_job(request.steps)
        if isinstance(job, tuple):
            return self._reply(response, "step_simulation", *job, steps=request.steps)
        code, message, _ = await job.future
        return self._reply(response, "step_simulation", code, message, steps=request.steps, done=job.done)

    # ---- the action -----------------------------------------------------------------------------------

    async def _simulate_steps(self, goal_handle):
        steps = goal_handle.request.steps

        def feedback(done: int, total: int) -> None:
            goal_handle.publish_feedback(SimulateSteps.Feedback(completed_steps=done, remaining_steps=total - done))

        job = self._start_job(steps, feedback, lambda: goal_handle.is_cancel_requested)
        if isinstance(job, tuple):
            code, message = job
            outcome, done = "aborted", 0
        else:
            code, message, outcome = await job.future
            done = job.done
        if outcome == "succeeded":
            goal_handle.succeed()
        elif outcome == "canceled":
            goal_handle.canceled()
        else:
            goal_handle.abort()
        self._event("simulate_steps", code, message, steps=steps, done=done, outcome=outcome)
        return SimulateSteps.Result(result=Result(result=code, error_message=message))


def _xyz(vector) -> tuple[float, float, float]:
    return (vector.x, vector.y, vector.z)


def _unknown(world, name: str) -> str:
    """The world's own "no body or flock named ..." message (it lists the entities there are)."""
    try:
        world.kind_of(name)
    except EditError as exc:
        return str(exc)
    return ""


#: a spawn job's refusal kind (cgp_sim_ros.spawning.Refusal) -> SpawnEntity's result code
_REFUSAL_CODES = {"unsupported_format": SpawnEntity.Response.UNSUPPORTED_FORMAT,
                  "parse_error": SpawnEntity.Response.RESOURCE_PARSE_ERROR,
                  "name_taken": SpawnEntity.Response.NAME_NOT_UNIQUE,
                  "name_invalid": SpawnEntity.Response.NAME_INVALID,
                  "invalid_pose": SpawnEntity.Response.INVALID_POSE,
                  "not_possible": FAILED}


class _NextTurn:
    """``await _NextTurn()``: give the executor back for one turn (it resumes the coroutine on its next spin)."""

    def __await__(self):
        yield

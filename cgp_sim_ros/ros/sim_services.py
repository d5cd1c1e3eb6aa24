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
- ``load_world`` (issue 36) is such a coroutine too: the scene is found, read, validated and drawn in the same
  worker process (:func:`cgp_sim_ros.worlds.prepare_world`; loads and spawns take turns there, in the order they
  came), and the world is rebuilt from it between two ticks (:meth:`SimNode.load_world`,
  :meth:`cgp_core.world.World.load`); ``spawn_entities`` prepares its whole batch in one job
  (:func:`cgp_sim_ros.spawning.prepare_batch`) and adds it all or nothing
  (:meth:`cgp_core.world.World.add_spawned_all`).  Entity info, bounds and named poses are the world's
  (:meth:`~cgp_core.world.World.entity_info`, :meth:`~cgp_core.world.World.entity_bounds`,
  :attr:`~cgp_core.world.World.named_poses`): the handlers only translate.

Simulation states (``SimulationState``): PLAYING (ticking), PAUSED (time stopped), STOPPED (paused and reset
to the scene as loaded; the state a paused world is in until it ticks or is set PAUSED / PLAYING; a world just
loaded), QUITTING (the reply is sent, then the node shuts down cleanly: the bag is finished), LOADING_WORLD (a
load_world is being prepared; the old world runs meanwhile), NO_WORLD (after unload_world: paused, nothing to
play).  Time never goes backwards: a
reset or STOPPED keeps the clock running (no ``SCOPE_TIME``), so TF buffers and bags stay consistent.
"""

from __future__ import annotations

import inspect
import time
import traceback
from dataclasses import dataclass, field

import numpy as np
from geometry_msgs.msg import Vector3
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.task import Future
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.msg import (
    Bounds,
    EntityCategory,
    EntityInfo,
    EntityState,
    NamedPose,
    Resource,
    Result,
    SimulationState,
    SimulatorFeatures,
    Spawnable,
    SpawnResult,
    TagsFilter,
    WorldResource,
)
from simulation_interfaces.srv import (
    DeleteEntity,
    GetAvailableWorlds,
    GetCurrentWorld,
    GetEntities,
    GetEntitiesStates,
    GetEntityBounds,
    GetEntityInfo,
    GetEntityState,
    GetNamedPoseBounds,
    GetNamedPoses,
    GetSimulationState,
    GetSimulatorFeatures,
    GetSpawnables,
    LoadWorld,
    ResetSimulation,
    SetEntityInfo,
    SetEntityState,
    SetSimulationState,
    SpawnEntities,
    SpawnEntity,
    StepSimulation,
    UnloadWorld,
)

from cgp_core.editing import WORLD_FRAMES, EditError
from cgp_core.entities import CATEGORIES, tags_match
from cgp_core.limits import MAX_YAML_BYTES
from cgp_core.scene import SceneError, available_scenes, scene_identity, spawnable_files

from .. import interface as itf
from ..spawning import SPAWN_FORMATS, Refusal, Spawned, SpawnRequest, brief, prepare, prepare_batch, warm_up
from ..workers import JobFailed, WorkerProcess
from ..worlds import WorldRequest, prepare_world
from . import process

OK = Result.RESULT_OK
NOT_FOUND = Result.RESULT_NOT_FOUND
UNSUPPORTED = Result.RESULT_FEATURE_UNSUPPORTED
INCORRECT_STATE = Result.RESULT_INCORRECT_STATE
FAILED = Result.RESULT_OPERATION_FAILED

#: spawn requests waiting for the spawn worker (one is prepared at a time); more are refused as busy
MAX_WAITING_SPAWNS = 8
#: the most entries one spawn_entities batch holds (each is a spawn request, prepared in one job)
MAX_BATCH_SPAWNS = 64

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
    # issue 36: the rest of simulation_interfaces 1.5
    SimulatorFeatures.WORLD_LOADING, SimulatorFeatures.WORLD_RESOURCE_STRING, SimulatorFeatures.WORLD_UNLOADING,
    SimulatorFeatures.WORLD_TAGS,
    SimulatorFeatures.WORLD_INFO_GETTING, SimulatorFeatures.AVAILABLE_WORLDS, SimulatorFeatures.SPAWNABLES,
    SimulatorFeatures.SPAWNING_ENTITIES, SimulatorFeatures.ENTITY_INFO_GETTING, SimulatorFeatures.ENTITY_INFO_SETTING,
    SimulatorFeatures.ENTITY_CATEGORIES, SimulatorFeatures.ENTITY_TAGS, SimulatorFeatures.ENTITY_BOUNDS,
    SimulatorFeatures.NAMED_POSES, SimulatorFeatures.POSE_BOUNDS,
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
    "SCOPE_TIME). get_entities filters: POSIX ERE on names, categories, tags, TYPE_SPHERE bounds. "
    "Worlds: cgp_sim's YAML scenes (load_world uri: a built-in name from get_available_worlds, a .yaml path or "
    "file:// URI; resource_string: scene YAML; world tags: the scene's tags:); loading replaces every entity "
    "between two ticks, time keeps "
    "running, the world is left STOPPED; unload_world leaves no world (STATE_NO_WORLD) until the next load. "
    "spawn_entities: all or nothing. Entity bounds: TYPE_BOX in the entity's frame (points[0] upper, points[1] "
    "lower corner). Named poses: the scene's named_poses section. See docs/simulation-interfaces.md."
)

_STATE_NAMES = {SimulationState.STATE_STOPPED: "STOPPED", SimulationState.STATE_PLAYING: "PLAYING",
                SimulationState.STATE_PAUSED: "PAUSED", SimulationState.STATE_QUITTING: "QUITTING",
                SimulationState.STATE_NO_WORLD: "NO_WORLD", SimulationState.STATE_LOADING_WORLD: "LOADING_WORLD"}
_SCOPE_TIME, _SCOPE_STATE, _SCOPE_SPAWNED = (ResetSimulation.Request.SCOPE_TIME, ResetSimulation.Request.SCOPE_STATE,
                                             ResetSimulation.Request.SCOPE_SPAWNED)
_SCOPE_ALL = (ResetSimulation.Request.SCOPE_DEFAULT, ResetSimulation.Request.SCOPE_ALL)
#: the standard's category numbers (EntityCategory) <-> cgp_core's names (cgp_core.entities.CATEGORIES)
_CATEGORY_NAMES = {number: name for name, number in CATEGORIES.items()}
assert all(getattr(EntityCategory, f"CATEGORY_{name.upper()}") == number for name, number in CATEGORIES.items())


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
        #: a load_world request is being prepared (STATE_LOADING_WORLD; the old world runs meanwhile)
        self.loading = False
        available_scenes()  # read once here, before the first tick (~0.16 s), not in get_available_worlds' reply
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
            (GetAvailableWorlds, itf.SERVICE_GET_AVAILABLE_WORLDS, self._get_available_worlds),
            (LoadWorld, itf.SERVICE_LOAD_WORLD, self._load_world),
            (UnloadWorld, itf.SERVICE_UNLOAD_WORLD, self._unload_world),
            (GetCurrentWorld, itf.SERVICE_GET_CURRENT_WORLD, self._get_current_world),
            (GetSpawnables, itf.SERVICE_GET_SPAWNABLES, self._get_spawnables),
            (SpawnEntities, itf.SERVICE_SPAWN_ENTITIES, self._spawn_entities),
            (GetEntityInfo, itf.SERVICE_GET_ENTITY_INFO, self._get_entity_info),
            (SetEntityInfo, itf.SERVICE_SET_ENTITY_INFO, self._set_entity_info),
            (GetEntityBounds, itf.SERVICE_GET_ENTITY_BOUNDS, self._get_entity_bounds),
            (GetNamedPoses, itf.SERVICE_GET_NAMED_POSES, self._get_named_poses),
            (GetNamedPoseBounds, itf.SERVICE_GET_NAMED_POSE_BOUNDS, self._get_named_pose_bounds),
        )
        # The stepping coroutines wait for the node's timer, which is in the node's default (mutually exclusive)
        # callback group: a coroutine in that group would hold it until it returns, and the timer would never
        # tick.  Their own reentrant group lets the timer run meanwhile (still one thread: no locks needed), and
        # lets a second stepping request be answered (refused) at once instead of queueing.
        stepping_group = ReentrantCallbackGroup()
        # spawn_entity, spawn_entities and load_world are coroutines too (they wait for the spawn worker)
        waiting = (StepSimulation, SpawnEntity, SpawnEntities, LoadWorld)
        self.services = [node.create_service(srv_type, name, self._guarded(name, callback),
                                             callback_group=stepping_group if srv_type in waiting else None)
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
        if self.loading:
            return SimulationState.STATE_LOADING_WORLD
        if not self.node.world.loaded:
            return SimulationState.STATE_NO_WORLD
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
        if not self.node.world.loaded:
            return INCORRECT_STATE, "no world is loaded (load_world first)"
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
        self.node.commands.take_arrived()  # what was sent before the request is applied by its first step
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
        """Names passing ``simulation_interfaces/msg/EntityFilters``: the name regex, categories, tags (any / all)
        and TYPE_SPHERE bounds are supported; other bounds are FEATURE_UNSUPPORTED."""
        world = self.node.world
        categories = []
        for k, category in enumerate(filters.categories):
            if category.category not in _CATEGORY_NAMES:
                return FAILED, f"filters.categories[{k}]: {category.category} is no category (valid: " \
                               f"{', '.join(f'{n} {c.upper()}' for c, n in CATEGORIES.items())})", []
            categories.append(_CATEGORY_NAMES[category.category])
        try:
            names = world.entity_names(filters.filter)
        except ValueError as exc:
            return FAILED, f"filters.filter: {exc}", []
        if categories or filters.tags.tags:
            names = world.entities_with_info(names, categories, list(filters.tags.tags),
                                             filters.tags.filter_mode == TagsFilter.FILTER_MODE_ALL)
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
        refusal = self._check_spawn(request)
        if refusal is not None:
            return (*refusal, "")
        if self._spawns_waiting >= MAX_WAITING_SPAWNS:
            return FAILED, self._busy(), ""
        async with _WorkerTurn(self):
            outcome = await self._run_job(prepare, self._spawn_request(request))
            if isinstance(outcome, tuple):
                return (*outcome, "")
            if isinstance(outcome, Refusal):
                return _REFUSAL_CODES.get(outcome.kind, FAILED), outcome.message, ""
            refusal = await self._kernels_for(self.node.convex_kernels.before_adding(outcome.prepared, self.node.world))
            if refusal is not None:
                return (*refusal, "")
            try:
                self.node.add_spawned(outcome.prepared, outcome.drawings)
            except EditError as exc:
                code = {"name_taken": R.NAME_NOT_UNIQUE, "name_invalid": R.NAME_INVALID,
                        "invalid_pose": R.INVALID_POSE}.get(exc.kind, FAILED)
                return code, str(exc), ""
        return OK, "", outcome.prepared.name

    def _check_spawn(self, request) -> tuple[int, str] | None:
        """The refusal of a spawn request that needs nothing read (code, message), or None."""
        R = SpawnEntity.Response
        if request.uri:
            pass
        elif request.resource_string:
            size = len(request.resource_string)
            if size > MAX_YAML_BYTES:  # refused before anything reads it (a character is at least one byte)
                return R.RESOURCE_PARSE_ERROR, (f"resource_string: {size} characters; at most {MAX_YAML_BYTES} "
                                                "bytes of YAML are parsed")
        else:
            return R.NO_RESOURCE, "uri and resource_string are both empty: give the entity as YAML (or a robot as URDF)"
        if request.entity_namespace:
            return UNSUPPORTED, (f"entity_namespace {brief(request.entity_namespace)}: not supported; an entity's "
                                 "topics are the node's (~/bodies/<name>/...)")
        frame = request.initial_pose.header.frame_id
        if self.node.frames.to_core(frame) not in WORLD_FRAMES:
            return R.INVALID_POSE, (f"initial_pose.header.frame_id {brief(frame)}: poses are given in "
                                    f"{self.node.frames.world!r} (or '')")
        if not request.name and not request.allow_renaming:
            return R.NAME_INVALID, "name is empty (and allow_renaming is false)"
        if not request.allow_renaming:  # a name already taken is refused before anything is read
            try:
                self.node.world.check_new_name(request.name)
            except EditError as exc:
                return (R.NAME_NOT_UNIQUE if exc.kind == "name_taken" else R.NAME_INVALID), str(exc)
        if self.quitting:
            return INCORRECT_STATE, "the simulator is quitting"
        if not self.node.world.loaded:
            return INCORRECT_STATE, "no world is loaded: nothing to spawn into (load_world first)"
        return None

    def _spawn_request(self, request) -> SpawnRequest:
        """What the spawn worker needs of ``request`` (a SpawnEntity request) and of the world now."""
        pose = request.initial_pose.pose
        return SpawnRequest(
            uri=request.uri, resource=request.resource_string if not request.uri else "",
            source=request.uri if request.uri else "resource_string",
            name=request.name, allow_renaming=request.allow_renaming,
            taken=frozenset(self.node.world.entity_names()),
            position=(pose.position.x, pose.position.y, pose.position.z),
            orientation=(pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w),
            world=self.node.world.scene.world)

    def _busy(self) -> str:
        return f"busy: {self._spawns_waiting} spawn or load requests are waiting (at most {MAX_WAITING_SPAWNS}); " \
               "try again"

    async def _run_job(self, function, argument):
        """``function(argument)`` in the spawn worker process, at most ``spawn_timeout`` seconds, awaited (the
        executor goes on meanwhile): its answer, or the refusal (code, message) of a job that gave none."""
        timeout = float(self.node.params["spawn_timeout"])
        job = self.spawn_worker.submit(function, argument, timeout=timeout)
        while not job.done():
            await _NextTurn()
        if self.quitting:
            return INCORRECT_STATE, "the simulator is quitting"
        try:
            return job.result()
        except JobFailed as failure:
            return FAILED, self._job_failure(failure, timeout)

    async def _kernels_for(self, loading) -> tuple[int, str] | None:
        """Wait for ``loading`` (a future of :class:`~cgp_sim_ros.ros.process.ConvexKernels`, or None): the
        kernels an entity or a scene needs, loaded off the tick's thread before it is added."""
        while loading is not None and not loading.done():
            await _NextTurn()
        if self.quitting:
            return INCORRECT_STATE, "the simulator is quitting"
        return None

    async def _spawn_entities(self, request, response):
        # each entry (msg/SpawnEntity: the resource in entity_resource) as the SpawnEntity request it stands for
        entries = [SpawnEntity.Request(name=e.name, allow_renaming=e.allow_renaming, uri=e.entity_resource.uri,
                                       resource_string=e.entity_resource.resource_string,
                                       entity_namespace=e.entity_namespace, initial_pose=e.initial_pose)
                   for e in request.spawn_requests]
        code, message, results = await self._spawn_batch(entries)
        response.results = results
        names = [r.entity_name for r in results if r.result.result == OK]
        return self._reply(response, "spawn_entities", code, message, (SpawnEntities.Response,),
                           count=len(request.spawn_requests), **({"entities": names} if names else {}))

    async def _spawn_batch(self, entries) -> tuple[int, str, list]:
        """``spawn_entities``: every entry checked (here, then in one job of the spawn worker,
        :func:`cgp_sim_ros.spawning.prepare_batch`) and added between two ticks, all of them or none
        (:meth:`cgp_core.world.World.add_spawned_all`).  Returns (code, message, SpawnResults)."""
        if not entries:
            return FAILED, "spawn_requests is empty: nothing to spawn", []
        if len(entries) > MAX_BATCH_SPAWNS:
            return FAILED, f"{len(entries)} spawn requests; a batch holds at most {MAX_BATCH_SPAWNS}", []
        refusals = {}
        names: dict[str, int] = {}
        for k, entry in enumerate(entries):
            refusal = self._check_spawn(entry)
            if refusal is None and not entry.allow_renaming and entry.name in names:
                refusal = (SpawnEntity.Response.NAME_NOT_UNIQUE, f"name {entry.name!r} is also entry "
                                                                 f"{names[entry.name]}'s")
            names.setdefault(entry.name, k)
            if refusal is not None:
                refusals[k] = refusal
        if not refusals and self._spawns_waiting >= MAX_WAITING_SPAWNS:
            return FAILED, self._busy(), []
        if not refusals:
            async with _WorkerTurn(self):
                requests = [self._spawn_request(entry) for entry in entries]
                answers = await self._run_job(prepare_batch, requests)
                if isinstance(answers, tuple):
                    return (*answers, [SpawnResult(result=Result(result=answers[0], error_message=answers[1]))
                                       for _ in entries])
                refusals = {k: (_REFUSAL_CODES.get(a.kind, FAILED), a.message) for k, a in enumerate(answers)
                            if isinstance(a, Refusal)}
                if not refusals:
                    added = await self._add_batch([a for a in answers if isinstance(a, Spawned)])
                    if isinstance(added, tuple):
                        code, message, k = added
                        refusals = {k: (code, message)}
                    else:
                        return OK, "", [SpawnResult(result=Result(result=OK), entity_name=name) for name in added]
        which = ", ".join(f"{k} ({entries[k].name or 'unnamed'})" for k in sorted(refusals))
        message = (f"{len(refusals)} of {len(entries)} entries refused: {which}; nothing was spawned (all or "
                   "nothing); each entry's result says why")
        results = [SpawnResult(result=Result(result=refusals[k][0], error_message=refusals[k][1])) if k in refusals
                   else SpawnResult(result=Result(result=FAILED, error_message=f"not spawned: {message}"))
                   for k in range(len(entries))]
        return SpawnEntities.Response.ENTITIES_SPAWN_FAILED, message, results

    async def _add_batch(self, spawned: list) -> list[str] | tuple[int, str, int]:
        """Add the batch's prepared entities (after their kernels are loaded): their names, or the refusal
        (code, message, entry) of the one the world refused — and then none is added."""
        for outcome in spawned:
            refusal = await self._kernels_for(self.node.convex_kernels.before_adding(outcome.prepared, self.node.world))
            if refusal is not None:
                return (*refusal, 0)
        try:
            self.node.add_spawned_all([s.prepared for s in spawned], [d for s in spawned for d in s.drawings])
        except EditError as exc:
            R = SpawnEntity.Response
            code = {"name_taken": R.NAME_NOT_UNIQUE, "name_invalid": R.NAME_INVALID,
                    "invalid_pose": R.INVALID_POSE}.get(exc.kind, FAILED)
            return code, str(exc), getattr(exc, "entry", 0)
        return [s.prepared.name for s in spawned]

    # ---- worlds -------------------------------------------------------------------------------------------------

    def _world_resource(self) -> WorldResource:
        world = self.node.world
        name, uri = scene_identity(world.scene.source)
        return WorldResource(name=name, world_resource=Resource(uri=uri), description=world.scene.description,
                             tags=list(world.scene.tags))

    def _get_available_worlds(self, request, response):
        if request.additional_sources:
            return self._reply(response, "get_available_worlds", UNSUPPORTED,
                               f"additional_sources {list(request.additional_sources)[:5]}: not searched; the built-in "
                               "scenes are listed, and load_world loads any scene file by its path")
        tags, match_all = list(request.filter.tags), request.filter.filter_mode == TagsFilter.FILTER_MODE_ALL
        response.worlds = [WorldResource(name=s.name, world_resource=Resource(uri=s.name), description=s.description,
                                         tags=list(s.tags))
                           for s in available_scenes() if tags_match(s.tags, tags, match_all)]
        return self._reply(response, "get_available_worlds", OK, count=len(response.worlds))

    def _get_current_world(self, request, response):
        if not self.node.world.loaded:
            return self._reply(response, "get_current_world", GetCurrentWorld.Response.NO_WORLD_LOADED,
                               "no world is loaded (unload_world was called; load_world loads one)",
                               (GetCurrentWorld.Response,))
        response.world = self._world_resource()
        return self._reply(response, "get_current_world", OK, world=response.world.name)

    async def _load_world(self, request, response):
        code, message = await self._load(request)
        if code == OK:
            response.world = self._world_resource()
        return self._reply(response, "load_world", code, message, (LoadWorld.Response,),
                           uri=request.uri or ("resource_string" if request.resource_string else ""),
                           **({"world": response.world.name} if code == OK else {}))

    async def _load(self, request) -> tuple[int, str]:
        """``load_world``: the scene found, read, validated and drawn in the spawn worker process (taking turns
        with the spawns: :func:`cgp_sim_ros.worlds.prepare_world`), its kernels loaded off the tick's thread,
        then the world replaced between two ticks (:meth:`SimNode.load_world`) and left STOPPED, as the standard
        says.  The old world keeps running until then, and stays if anything is refused."""
        R = LoadWorld.Response
        if not request.uri and not request.resource_string:
            return R.NO_RESOURCE, "uri and resource_string are both empty: name a world (get_available_worlds)"
        if not request.uri and len(request.resource_string) > MAX_YAML_BYTES:
            return R.RESOURCE_PARSE_ERROR, (f"resource_string: {len(request.resource_string)} characters; at most "
                                            f"{MAX_YAML_BYTES} bytes of YAML are parsed")
        if request.ignore_missing_or_unsupported_assets:
            return UNSUPPORTED, ("ignore_missing_or_unsupported_assets: not supported; a scene is loaded whole or "
                                 "not at all (a missing mesh or URDF is refused, naming it)")
        if self.quitting:
            return INCORRECT_STATE, "the simulator is quitting"
        if self._spawns_waiting >= MAX_WAITING_SPAWNS:
            return FAILED, self._busy()
        self.loading = True
        try:
            async with _WorkerTurn(self):
                outcome = await self._run_job(prepare_world, WorldRequest(uri=request.uri,
                                                                          resource=request.resource_string))
                if isinstance(outcome, tuple):
                    return outcome
                if isinstance(outcome, Refusal):
                    return _WORLD_REFUSAL_CODES.get(outcome.kind, FAILED), outcome.message
                refusal = await self._kernels_for(self.node.convex_kernels.before_loading(outcome))
                if refusal is not None:
                    return refusal
                building = process.build_world(self.node.world, outcome.scene, self.node.outputs.build_for_another)
                refusal = await self._kernels_for(building)
                if refusal is not None:
                    return refusal
                new = building.result()
                if isinstance(new, SceneError):  # e.g. the node's substeps with this scene's shapes
                    return R.RESOURCE_PARSE_ERROR, str(new)
                if isinstance(new, Exception):
                    self.node.get_logger().error(f"load_world: building the world failed: {new!r}")
                    return FAILED, f"internal error building the world: {new!r}"
                self.node.load_world(new, outcome.drawings)
        finally:
            self.loading = False
        self._abort_job("interrupted: another world was loaded")
        self.node.paused = True
        self.stopped = True
        return OK, ""

    def _unload_world(self, request, response):
        if not self.node.world.loaded:
            return self._reply(response, "unload_world", UnloadWorld.Response.NO_WORLD_LOADED,
                               "no world is loaded", (UnloadWorld.Response,))
        if self.loading:
            return self._reply(response, "unload_world", INCORRECT_STATE, "a world is loading; try again when it is "
                               "loaded")
        self._abort_job("interrupted: the world was unloaded")
        self.node.load_world(None)
        self.node.paused = True
        self.stopped = False
        return self._reply(response, "unload_world", OK)

    # ---- what the simulator can spawn ---------------------------------------------------------------------------

    def _get_spawnables(self, request, response):
        response.spawnables = [Spawnable(uri=f.name, description=f.description) for f in spawnable_files()] + [
            Spawnable(uri="", description=f"resource_string (YAML): {text}") for text in _ENTRY_TEMPLATES]
        message = (f"sources {list(request.sources)[:5]}: not recognized (the built-in robots and meshes are "
                   "listed; spawn_entity takes any .urdf/.xacro/.yaml/.stl/.obj file by its path)"
                   if request.sources else "")
        return self._reply(response, "get_spawnables", OK, message, count=len(response.spawnables))

    # ---- entity info and bounds -----------------------------------------------------------------------------

    def _get_entity_info(self, request, response):
        try:
            info = self.node.world.entity_info(request.entity)
        except EditError as exc:
            return self._reply(response, "get_entity_info", NOT_FOUND, str(exc), entity=request.entity)
        response.info = EntityInfo(category=EntityCategory(category=CATEGORIES[info.category]),
                                   description=info.description, tags=list(info.tags))
        return self._reply(response, "get_entity_info", OK, entity=request.entity)

    def _set_entity_info(self, request, response):
        info = request.info
        category = _CATEGORY_NAMES.get(info.category.category)
        if category is None:
            return self._reply(response, "set_entity_info", FAILED,
                               f"info.category {info.category.category}: not one of "
                               f"{', '.join(f'{n} {c.upper()}' for c, n in CATEGORIES.items())}",
                               entity=request.entity)
        try:
            self.node.world.set_entity_info(request.entity, category, info.description, list(info.tags))
        except EditError as exc:
            return self._reply(response, "set_entity_info", NOT_FOUND if exc.kind == "unknown" else FAILED,
                               str(exc), entity=request.entity)
        return self._reply(response, "set_entity_info", OK, entity=request.entity, category=category)

    def _get_entity_bounds(self, request, response):
        try:
            bounds = self.node.world.entity_bounds(request.entity)
        except EditError as exc:
            return self._reply(response, "get_entity_bounds", NOT_FOUND, str(exc), entity=request.entity)
        response.bounds = Bounds(type=Bounds.TYPE_EMPTY) if bounds is None else _box(*bounds)
        return self._reply(response, "get_entity_bounds", OK, entity=request.entity)

    # ---- named poses ------------------------------------------------------------------------------------------

    def _get_named_poses(self, request, response):
        tags, match_all = list(request.tags.tags), request.tags.filter_mode == TagsFilter.FILTER_MODE_ALL
        poses = [p for p in self.node.world.named_poses if tags_match(p.tags, tags, match_all)]
        response.poses = [_named_pose(p) for p in poses]
        return self._reply(response, "get_named_poses", OK, count=len(poses))

    def _get_named_pose_bounds(self, request, response):
        try:
            pose = self.node.world.named_pose(request.name)
        except EditError as exc:
            return self._reply(response, "get_named_pose_bounds", NOT_FOUND, str(exc), name=request.name)
        bounds = pose.bounds
        if bounds is None:
            response.bounds = Bounds(type=Bounds.TYPE_EMPTY)
        elif bounds.radius is not None:
            response.bounds = Bounds(type=Bounds.TYPE_SPHERE, points=[_vector(pose.position),
                                                                      Vector3(x=float(bounds.radius))])
        else:
            response.bounds = _box(pose.position + bounds.lower, pose.position + bounds.upper)
        return self._reply(response, "get_named_pose_bounds", OK, name=request.name)

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
            return R.INCORRECT_TRANSITION, (f"{_STATE_NAMES[target]}: not a state to set; load_world and "
                                            "unload_world load and unload worlds")
        if target not in (S.STATE_STOPPED, S.STATE_PLAYING, S.STATE_PAUSED, S.STATE_QUITTING):
            return R.INCORRECT_TRANSITION, f"unknown state {target} (valid: 0 STOPPED, 1 PLAYING, 2 PAUSED, " \
                                           "3 QUITTING)"
        if current == S.STATE_QUITTING:
            return R.INCORRECT_TRANSITION, "the simulator is quitting"
        if current in (S.STATE_NO_WORLD, S.STATE_LOADING_WORLD) and target != S.STATE_QUITTING:
            return R.INCORRECT_TRANSITION, (f"{_STATE_NAMES[current]}: no world to start, stop or pause "
                                            "(load_world first)" if current == S.STATE_NO_WORLD
                                            else "LOADING_WORLD: a world is loading; try again when it is loaded")
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


#: a load_world job's refusal kind (cgp_sim_ros.worlds) -> LoadWorld's result code
_WORLD_REFUSAL_CODES = {"not_found": NOT_FOUND, "unsupported_format": LoadWorld.Response.UNSUPPORTED_FORMAT,
                        "parse_error": LoadWorld.Response.RESOURCE_PARSE_ERROR}

#: what get_spawnables lists besides the files: the scene entries spawn_entity takes as YAML
_ENTRY_TEMPLATES = (
    "{body: {shape: sphere, radius: 0.3, mass: 2.0}}",
    "{body: {shape: box, size: [0.4, 0.4, 0.4], mass: 2.0}}",
    "{body: {shape: capsule, radius: 0.2, length: 1.0, mass: 3.0}}",
    "{body: {shape: particles, radius: 0.15, particles: [[0, 0, 0, 1], [0.3, 0, 0, 1]]}}",
    "{body: {shape: convex, mesh: rock.stl}} (or points: [[x, y, z], ...])",
    "{body: {shape: compound, parts: [{shape: box, size: [1, 1, 1]}, ...]}}",
    "{body: {shape: mesh, mesh: terrain.obj, fixed: true}}",
    "{flock: {count: 100}}",
    "{robot: {urdf: arm.urdf}}",
)


def _vector(values) -> Vector3:
    return Vector3(x=float(values[0]), y=float(values[1]), z=float(values[2]))


def _box(lower, upper) -> Bounds:
    """TYPE_BOX bounds: the standard's order, "upper right and lower left corners" (points[0] the upper)."""
    return Bounds(type=Bounds.TYPE_BOX, points=[_vector(upper), _vector(lower)])


def _named_pose(spec) -> NamedPose:
    msg = NamedPose(name=spec.name, description=spec.description, tags=list(spec.tags))
    p, q = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = map(float, spec.position)
    q.x, q.y, q.z, q.w = map(float, spec.orientation)
    return msg


class _WorkerTurn:
    """``async with _WorkerTurn(sim):`` the spawn worker for one request (spawns and world loads take turns, in
    the order they came); counted as waiting (MAX_WAITING_SPAWNS) until it is done."""

    def __init__(self, sim: SimulationInterfaces):
        self.sim = sim

    async def __aenter__(self):
        self.sim._spawns_waiting += 1
        while self.sim._spawn_running:
            await _NextTurn()
        self.sim._spawn_running = True
        return self

    async def __aexit__(self, *exc_info):
        self.sim._spawn_running = False
        self.sim._spawns_waiting -= 1
        return False


class _NextTurn:
    """``await _NextTurn()``: give the executor back for one turn (it resumes the coroutine on its next spin)."""

    def __await__(self):
        yield

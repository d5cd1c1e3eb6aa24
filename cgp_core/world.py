"""The World: one scene's model and state, and the step pipeline.

``World.step()`` advances one *tick* of ``dt`` seconds (the node's ``1 / rate_hz``):

1. rigid bodies, unless all sleep: ``substeps`` sub-steps of ``h = dt / substeps``, each
   apply wrench commands → :func:`cgp_core.dynamics.step_bodies` (forces, contacts, solve, integrate,
   recover penetration, clear accumulators — the stages are named there; sleeping islands are left out);
2. contain blow-ups: a body whose state went non-finite or absurd is put back to its initial state (reported
   in :attr:`World.events`); the rest of the world goes on;
   then sleep, per island (:mod:`cgp_core.sleep`): an island of touching movable bodies that have all stayed
   slower than :data:`SLEEP_SPEED` for :data:`SLEEP_TIME` falls asleep (momenta zeroed, left out of stage 1)
   until a wrench command on one of its bodies, an awake body touching it, :meth:`World.reset` or
   :meth:`World.wake` wakes it;
3. flocks: one step of ``dt`` each, avoiding the bodies at their end-of-tick poses and fleeing those marked
   ``predator`` (a flock whose state went non-finite is reset, and reported, the same way);
4. wrench schedule: count the tick off timed wrenches.

Usage (no ROS needed)::

    from cgp_core import World
    world = World.from_scene("default")
    world.apply_wrench("crate", force=[0, 0, 50], point=[0.2, 0, 0])   # world frame, for one tick
    for _ in range(60):
        world.step()
    print(world.time, world.body_state.position)

Editing it while it runs (what the node's ``simulation_interfaces`` services call): :meth:`World.spawn` a body or
a flock from a scene-format entry, :meth:`World.delete` one, :meth:`World.set_body_state` (teleport) /
:meth:`World.move_flock`, :meth:`World.entity_state` / :meth:`World.entity_names` to ask; :meth:`World.reset`
with a scope.  The model is replaced by a new object on every spawn / delete (see :mod:`cgp_core.editing`).

Changing the bodies between ticks (spawn, delete, teleport) — the contract the rigid-body pipeline keeps:

- ``body_model`` is static while stepping, and may be **replaced by a new object** between ticks (bodies
  appended or removed, its arrays built by concatenating or selecting), with ``body_state`` replaced to match.
  Every per-body cache of the pipeline is keyed on the model object and its body count, and rebuilt when either
  changes: the collision primitives (``solver.detector``), the warm-start impulses (``solver``: a new model
  starts cold), the islands and rest timers (:class:`cgp_core.sleep.Islands`: every body awake), the compiled
  kernels' work arrays (allocated per call).  Nothing per-body is carried over from the old model.
- A body's state may be edited in place between ticks (a teleport: position, orientation, momenta); then call
  :meth:`World.wake` with that body (``world.wake([i])`` or ``world.wake(["crate"])``), which wakes its island
  (a sleeping body would otherwise stay where it slept, ignoring the edit for collisions with other sleepers).
  The warm-start impulses of its old contacts are matched by position and fade out on their own.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .bodies import tensor_times, world_tensor
from .boids import Flock, Obstacles
from .boids.predators import Predators
from .dynamics import Ground, step_bodies
from .editing import (
    EditError,
    EntityState,
    body_distances,
    check_pose,
    check_vector,
    concatenate_bodies,
    name_filter,
    select_bodies,
)
from .entities import EntityInfo, body_frame_bounds, box_corners, check_info, default_body_info, tags_match
from .integrators import make_integrator
from .limits import (
    BLOWUP_SPEED,
    BLOWUP_SPIN,
    MAX_BODIES,
    MAX_BOIDS,
    MAX_COORDINATE,
    MAX_NAME_LENGTH,
    MAX_SPEED,
    MAX_SPIN,
    rigid_work_refusal,
)
from .robots.trajectory import Following
from .robots.world import Robots
from .rotation import matrix_to_quat, quat_conjugate, quat_rotate, quat_to_matrix
from .scene import (
    GROUND_NAME,
    ROS_SAFE_NAME,
    Scene,
    SceneError,
    WorldSpec,
    body_reach,
    load_scene,
    spawn_entry,
)
from .sleep import SLEEP_SPEED, SLEEP_TIME, Islands
from .solver import make_solver
from .solver.report import ContactReport, carry_sleeping
from .wrenches import DEFAULT_LIMITS, CommandLimits, WrenchCommand, WrenchSchedule, make_command

#: a body moving faster than BLOWUP_SPEED [m/s] or spinning faster than BLOWUP_SPIN [rad/s] has blown up
#: numerically (the values live with the other limits, in cgp_core.limits)

#: Sleeping per island, as Box2D does it (SLEEP_SPEED [m/s], SLEEP_TIME [s]: see :mod:`cgp_core.sleep`).
#: Boids steer around bodies but never push them, so they never wake one.  ``world.sleep: false`` in a scene
#: turns sleeping off.
__all__ = ["World", "WorldEvent", "SLEEP_SPEED", "SLEEP_TIME", "BLOWUP_SPEED", "BLOWUP_SPIN"]


@dataclass
class PreparedSpawn:
    """A validated entity, built and ready to add (:meth:`World.prepare_spawn`): a body's model and state rows
    (one body) or a flock with its initial state."""

    kind: str  # "body" | "flock" | "robot"
    name: str
    model: object = None  # BodyModel of the one body (a robot: of its links, <name>/<link>)
    state: object = None  # its BodyState
    flock: object = None  # Flock
    robot: object = None  # a robot's RobotSpec (cgp_core.scene.robots), placed at the spawn pose
    #: what loading it had to say (BodySpec.notes: a hull of non-convex points, a BVH built), reported as events
    #: when it is added
    notes: list = field(default_factory=list)


def prepare_spawn(entry, world_spec, *, name: str, taken: set[str], position=(0.0, 0.0, 0.0),
                  orientation=(0.0, 0.0, 0.0, 1.0), source: str = "<spawn>") -> PreparedSpawn:
    """:meth:`World.prepare_spawn` for a world whose scene settings are ``world_spec`` (a
    :class:`~cgp_core.scene.WorldSpec`): it needs nothing else of the world, so it runs anywhere — another
    thread, another process — while the world steps."""
    check_name(name)
    if name in taken:
        raise EditError("name_taken", f"name {name!r} is taken")
    position, orientation = check_pose(position, orientation, "initial_pose")
    kind, spec = spawn_entry(entry, source, name=name, taken=taken, position=position, orientation=orientation)
    if kind == "flock":
        if abs(abs(float(orientation[3])) - 1.0) > 1e-9:
            raise EditError("invalid_pose", "initial_pose.orientation: a flock has no orientation (the boids "
                            "have their own); give the identity (0, 0, 0, 1)")
        return PreparedSpawn(kind, name, flock=Flock(spec))
    if kind == "robot":
        try:
            links = Robots([spec]).body_specs()  # its links' bodies at its initial joint positions
        except ValueError as exc:  # more joint velocities than a world holds
            raise EditError("not_possible", str(exc)) from None
        model, state = Scene(source, world_spec, links, []).build_bodies()
        return PreparedSpawn(kind, name, model=model, state=state, robot=spec, notes=list(spec.notes))
    model, state = Scene(source, world_spec, [spec], []).build_bodies()
    return PreparedSpawn(kind, name, model=model, state=state, notes=list(spec.notes))


def check_name(name) -> None:
    """:class:`EditError` ``name_invalid`` unless ``name`` is ROS-safe and at most MAX_NAME_LENGTH characters."""
    if not isinstance(name, str) or len(name) > MAX_NAME_LENGTH or not ROS_SAFE_NAME.match(name):
        shown = name if not isinstance(name, str) or len(name) <= MAX_NAME_LENGTH else name[:MAX_NAME_LENGTH] + "..."
        raise EditError("name_invalid", f"name {shown!r} is not usable: names are ROS-safe (letters, digits, _; "
                        f"starting with a letter) and at most {MAX_NAME_LENGTH} characters (they become parts of "
                        "topic names)")
    if name == GROUND_NAME:
        raise EditError("name_invalid", f"name {name!r} is reserved: it names the ground plane in contact reports")


def unique_name(base: str, taken: set[str]) -> str:
    """``base`` if not in ``taken``, else ``base_2``, ``base_3``, ... (the first free one)."""
    base = base[:MAX_NAME_LENGTH - 8]
    taken = taken | {GROUND_NAME}
    if base not in taken:
        return base
    k = 2
    while f"{base}_{k}" in taken:
        k += 1
    return f"{base}_{k}"


def _entry_error(exc: EditError, entry: int, name: str) -> EditError:
    """``exc`` about entry ``entry`` of a spawn batch: the message names it, ``.entry`` holds it."""
    error = EditError(exc.kind, f"entry {entry} ({name}): {exc}")
    error.entry = entry
    return error


@dataclass
class WorldEvent:
    """Something the world did on its own that a user should hear about (the node logs these)."""

    time: float
    level: str  # "info" | "warn" | "error"
    text: str


class World:
    """A scene, stepping.  Attributes:

    scene:        the validated :class:`~cgp_core.scene.Scene`.
    dt:           tick length [s]; ``substeps`` physics sub-steps of ``dt / substeps`` per tick.
    time_ns:      simulated time [ns] since the start, an exact integer sum of the ticks (keeps running across
                  :meth:`reset`, so clocks and recordings never go backwards); ``time`` in seconds.
    ticks:        ticks taken.
    body_model:   static :class:`~cgp_core.bodies.BodyModel`;  body_state: dynamic :class:`BodyState`.
    flocks:       list of :class:`~cgp_core.boids.Flock`.
    events:       list of :class:`WorldEvent` not yet collected (see :meth:`take_events`).
    spawned:      names of the bodies and flocks spawned at run time (not from the scene), in spawn order.
    model_version: counts the replacements of ``body_model`` / ``flocks`` (spawn, delete, reset of spawned
                  entities, a scene loaded): whoever keeps per-body or per-flock things (publishers,
                  serializers) rebuilds them when it changes.
    loaded:       False after :meth:`unload`; :meth:`load` puts another scene into this very object.
    """

    def __init__(self, scene: Scene, *, dt: float = 1.0 / 60.0, substeps: int | None = None,
                 seed: int | None = None):
        self.scene = scene
        #: the caller's sub-steps and seed, kept for the scenes :meth:`load` builds later
        self._substeps_arg, self._seed = substeps, seed
        #: False after :meth:`unload` (an empty world that still steps: time keeps running)
        self.loaded = True
        #: what :meth:`set_entity_info` was told, by entity name (the others have :meth:`entity_info`'s default)
        self._info: dict[str, EntityInfo] = {}
        self.set_dt(dt)
        self.substeps = int(substeps if substeps is not None else scene.world.substeps)
        if self.substeps < 1:
            raise ValueError(f"substeps must be >= 1, got {self.substeps}")
        self.gravity = np.asarray(scene.world.gravity, dtype=float)
        self.ground = Ground(friction=scene.world.ground_friction,
                             restitution=scene.world.ground_restitution) if scene.world.ground else None
        self.integrator = make_integrator(scene.world.integrator)
        self.solver = make_solver(rolling_resistance=scene.world.rolling_resistance)
        # ``world.contact_detection``: contacts found every sub-step, or once per tick and carried through its
        # sub-steps (cgp_core.collision.carry)
        self.solver.detector.carrying = scene.world.contact_detection == "once_per_tick"
        # a scene file's own sub-steps were checked when it was loaded; these may be the caller's (the node's)
        refusal = rigid_work_refusal(*scene.rigid_work(), self.substeps)
        if refusal:
            raise SceneError(scene.source, [f"{'world.' if substeps is None else ''}substeps: {refusal}"])
        #: the scene's robots (:class:`cgp_core.robots.world.Robots`; their links are bodies named <robot>/<link>)
        #: and the articulations of its joints: bodies that keep their names, cgp_core.robots.articulations)
        robot_specs = list(scene.robots) + list(getattr(scene, "articulations", []))
        self._scene_robot_specs = robot_specs
        self.robots = Robots(robot_specs) if robot_specs else None
        self.body_model, self._initial_body_state = self._scene_bodies()
        self.body_state = self._initial_body_state.copy()
        if self.robots is not None:
            self.robots.attach(self.body_model)
            self.solver.detector.exclude(*self.robots.exclusion)
        self._scene_flock_params = [p if seed is None else p.with_seed(seed + i) for i, p in enumerate(scene.flocks)]
        self.flocks = [Flock(p) for p in self._scene_flock_params]
        self.wrenches = WrenchSchedule()
        # a robot's links, and a scene's jointed bodies, are one sleep island each (Robots.joined_pairs)
        self.sleep_enabled = bool(scene.world.sleep)
        self._islands: Islands | None = None  # per-island sleep state of body_model (see islands())
        self.time_ns = 0
        self.ticks = 0
        self.events: list[WorldEvent] = []
        self.spawned: list[str] = []
        self.model_version = 0
        for body in scene.bodies:  # what loading the bodies had to say (a hull of non-convex points, a BVH built)
            self._report_notes(body)
        #: sum each tick's contacts into :attr:`contacts` (off by default: it costs a compiled call per sub-step)
        self.report_contacts = False
        #: the last reported tick's :class:`~cgp_core.solver.report.ContactReport` (with ``report_contacts``)
        self.contacts = ContactReport.empty()
        self._contacts_of = (None, -1)  # the body model `contacts` indexes and the tick it is of
        #: the scene trajectories (``robots[].trajectory``) the robots follow, from time 0 (cgp_core/robots/
        #: trajectory.py); a joint command stops a robot's (:meth:`stop_trajectory`)
        self.trajectories = Following()
        self.trajectories.start(self.robots, self.time_ns)
        self.remember_tick_start()

    def _report_notes(self, spec) -> None:
        self.events.extend(WorldEvent(self.time, level, text) for level, text in getattr(spec, "notes", ()))

    @classmethod
    def from_scene(cls, scene: str | Scene, **kwargs) -> World:
        """A world from a scene file path, a built-in scene name, or a parsed :class:`Scene`."""
        return cls(scene if isinstance(scene, Scene) else load_scene(scene), **kwargs)

    # ---- stepping -------------------------------------------------------------------------------------

    def step(self) -> None:
        """Advance one tick (see the module docstring for the stages)."""
        h = self.dt / self.substeps
        if self.trajectories.robots:  # the scene trajectories' targets for the end of this tick
            for level, text in self.trajectories.command(self.robots, self.time_ns + self.dt_ns):
                self.events.append(WorldEvent(self.time, level, text))
        self.remember_tick_start()
        model, state = self.body_model, self.body_state
        islands = self.islands()
        if islands is not None and self.wrenches.active:
            islands.wake(self.wrenches.body)  # a wrench wakes the island of the body it acts on
        if islands is not None and self.robots is not None:
            commanded = self.robots.take_commanded()  # a joint command wakes its robot's island
            if commanded.size:
                islands.wake(commanded)
        if (model.count or self.robots is not None) and not self.bodies_asleep:
            # An extreme (but accepted) force can overflow a body's state to inf / NaN within the sub-steps;
            # numpy's warnings about it would only repeat, on stderr, what _contain_blowups reports right
            # after as an event naming the body.
            if self.report_contacts:
                self.solver.start_report()
                if self.robots is not None:  # the link contacts are solved (and summed) in the robot stage
                    self.robots.start_report(model.count)
            detector = self.solver.detector
            with np.errstate(over="ignore", invalid="ignore"):
                for k in range(self.substeps):
                    self.wrenches.apply(state)
                    if detector.carrying:  # (cgp_core.collision.carry)
                        detector.carry_next = k > 0
                    contacts = step_bodies(model, state, self.integrator, self.solver, h, gravity=self.gravity,
                                           ground=self.ground, damping=(self.scene.world.linear_damping,
                                                                        self.scene.world.angular_damping),
                                           islands=islands,
                                           robots=self.robots)
                detector.carry_next = False  # (a detect between ticks detects)
            if self.robots is not None:
                self.robots.end_tick()
            if self.report_contacts:
                self._report_contacts(model, islands)  # before sleep: who slept *during* the sub-steps
            if self.robots is not None:
                for name in self.robots.contain_blowups(model, state):
                    self.events.append(WorldEvent(self.time, "error", f"numerical blow-up of robot {name} (a "
                                                  "joint state non-finite or a link beyond the blow-up speeds): "
                                                  "reset to its initial joint positions at rest, its drives "
                                                  "holding them"))
                for name, count in self.robots.take_fallbacks():
                    self.events.append(WorldEvent(self.time, "warn", f"robot {name}: its Gauss–Legendre joint "
                                                  f"integrator did not converge in {count} sub-step(s) of this "
                                                  "tick, which took the default semi-implicit Euler step"))
            self._update_sleep(contacts, *self._contain_blowups())
        elif self.report_contacts:
            self._report_contacts(model, islands)  # everything asleep (or no bodies): the last contacts hold
        if self.flocks:
            obstacles = Obstacles.from_bodies(model, state, ground=self.ground is not None) \
                if model.count or self.ground is not None else None
            predators = Predators.from_bodies(model, state)  # bodies marked `predator`: every flock flees them
            for flock in self.flocks:
                flock.step(self.dt, obstacles, predators)
            self._contain_flock_blowups()
        self.wrenches.end_tick()
        self.ticks += 1
        self.time_ns += self.dt_ns

    def _report_contacts(self, model, islands) -> None:
        """The tick's :attr:`contacts` (:mod:`cgp_core.solver.report`): the solver's sums over the sub-steps, and
        the contacts of the islands that slept through them, held from the tick before."""
        report = self.solver.finish_report(self.dt)
        if self.robots is not None:
            report = self.robots.finish_report(report, self.dt)
        previous = self.contacts
        held_model, held_tick = self._contacts_of
        # `is`, not ==: a body model is a dataclass of arrays, whose == is ambiguous (a spawn replaces the model)
        if islands is not None and held_model is model and held_tick == self.ticks - 1:  # the tick before, same bodies
            report = carry_sleeping(report, previous, islands.asleep, model.fixed, self.body_state.position)
        self.contacts, self._contacts_of = report, (model, self.ticks)

    @property
    def time(self) -> float:
        """Simulated time [s]."""
        return self.time_ns * 1e-9

    def set_dt(self, dt: float) -> None:
        """Set the tick length (from the next tick on).  It is rounded to whole nanoseconds and the physics
        uses exactly that value, so ``time_ns`` (what /clock and the bag carry) is the exact sum of the steps
        taken, with no drift between the clock and the physics."""
        if not (isinstance(dt, (int, float)) and np.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
        self.dt_ns = max(1, round(dt * 1e9))
        self.dt = self.dt_ns * 1e-9

    def _contain_blowups(self) -> tuple[np.ndarray, np.ndarray]:
        """Reset every blown-up body; returns the bodies' speeds ``|v|``, ``|ω|`` (n,) each, after it (a reset
        body is at rest), for :meth:`_update_sleep`."""
        model, state = self.body_model, self.body_state
        finite = (np.isfinite(state.position).all(1) & np.isfinite(state.orientation).all(1)
                  & np.isfinite(state.linear_momentum).all(1) & np.isfinite(state.angular_momentum).all(1))
        # a blown-up body's speeds overflow or are NaN here: that is what this check is for, not a warning
        with np.errstate(over="ignore", invalid="ignore"):
            speed = np.linalg.norm(state.linear_velocity(model), axis=1)
            spin = np.linalg.norm(state.angular_velocity(model), axis=1)
            sane = finite & (speed < BLOWUP_SPEED) & (spin < BLOWUP_SPIN)
        bad = np.flatnonzero(~sane)
        if bad.size == 0:
            return speed, spin
        speed[bad] = 0.0
        spin[bad] = 0.0
        init = self._initial_body_state
        for name in ("position", "orientation", "linear_momentum", "angular_momentum"):
            getattr(state, name)[bad] = getattr(init, name)[bad]
        if state.rotation is not None:
            state.rotation[bad] = init.rotation_matrices()[bad]
        state.linear_momentum[bad] = 0.0
        state.angular_momentum[bad] = 0.0
        self.wrenches.remove_bodies(bad)  # the wrench that blew it up would do it again
        if self._islands is not None and self._islands.matches(model):
            self._islands.wake(bad)
        names = ", ".join(model.names[i] for i in bad)
        self.events.append(WorldEvent(self.time, "error",
                                      f"numerical blow-up of {names} (non-finite or > {BLOWUP_SPEED:g} m/s): "
                                      "reset to its initial pose at rest and its wrenches cleared"))
        return speed, spin

    def islands(self) -> Islands | None:
        """The per-island sleep state of the current ``body_model`` (``None`` with ``world.sleep: false``),
        rebuilt — every body awake — when the model object or its body count changed."""
        if not self.sleep_enabled:
            return None
        if self._islands is None or not self._islands.matches(self.body_model):
            self._islands = Islands(self.body_model)
        return self._islands

    @property
    def bodies_asleep(self) -> bool:
        """True while every movable body sleeps (the rigid-body sub-steps are skipped)."""
        islands = self.islands()
        return islands is not None and islands.all_asleep

    @property
    def rest_time(self) -> float:
        """How long [s] the least rested awake movable body has been resting (0 when none is awake)."""
        islands = self.islands()
        if islands is None or not islands.awake.any():
            return 0.0
        return float(islands.rest_time[islands.awake].min())

    def _update_sleep(self, contacts, speed: np.ndarray, spin: np.ndarray) -> None:
        """Islands from the last sub-step's ``contacts``, rest timers from ``speed`` = |v|, ``spin`` = |ω| (n,)
        each; islands rested for :data:`SLEEP_TIME` fall asleep with zero momenta, so they stay exactly where
        they rest (:meth:`cgp_core.sleep.Islands.update`)."""
        islands = self.islands()
        if islands is None:
            return
        joined = None if self.robots is None else self.robots.joined_pairs()
        islands.update(self.body_state, self.body_model, contacts.body_a, contacts.body_b, speed, spin, self.dt,
                       joined)
        if self.robots is not None:
            self.robots.hold_sleeping(islands.awake)  # a sleeping robot's joint velocities zeroed with its momenta

    def wake(self, bodies=None) -> None:
        """Wake sleeping bodies: ``None`` = all; else the islands of ``bodies`` (indices or names).  A wrench
        command, a touch and reset do it by themselves; call it after editing ``body_state`` by hand (a
        teleport)."""
        islands = self.islands()
        if islands is None:
            return
        if bodies is None:
            islands.wake()
            return
        index = [self.body_model.index(b) if isinstance(b, str) else int(b) for b in np.atleast_1d(bodies)]
        for i in index:
            if not 0 <= i < self.body_model.count:
                raise IndexError(f"body index {i} out of range: there are {self.body_model.count} bodies")
        islands.wake(index)

    def _contain_flock_blowups(self) -> None:
        """A flock whose state went non-finite is put back to its initial state (the boids' speeds are clamped,
        so only a numerical fault gets here); one check per flock, O(N) and cheap next to the step."""
        for flock in self.flocks:
            if np.isfinite(flock.positions).all() and np.isfinite(flock.velocities).all() \
                    and np.isfinite(flock.orientations).all():
                continue
            flock.reset()
            self.events.append(WorldEvent(self.time, "error", f"numerical blow-up of flock {flock.params.name} "
                                          "(non-finite boid state): reset to its initial state"))

    def take_events(self) -> list[WorldEvent]:
        events, self.events = self.events, []
        return events

    # ---- commands -------------------------------------------------------------------------------------

    def reset(self, *, state: bool = True, spawned: bool = True) -> None:
        """Back to the initial state; ``time`` keeps running (clocks and recordings never go backwards).

        ``spawned``: delete every body and flock spawned at run time.  ``state``: every remaining body and flock
        back to its initial state (a spawned one to its spawn state) and wrenches cleared.  The default (both)
        is the scene as loaded."""
        if state and spawned and self.entity_names() != self._scene_names():
            self._restore_scene()  # deleted scene entities come back too, as if the world were loaded again
        elif spawned and self.spawned:
            self._remove(list(self.spawned))
        if state:
            self.body_state = self._initial_body_state.copy()
            if self.robots is not None:
                self.robots.reset()
                self.robots.write_bodies(self.body_model, self.body_state)
            self.trajectories.start(self.robots, self.time_ns)  # the scene trajectories from their start again
            for flock in self.flocks:
                flock.reset()
            self.wrenches.clear()
            self.remember_tick_start()
            if hasattr(self.solver, "reset"):
                self.solver.reset()
        self.wake()

    def apply_wrench(self, body: str, force=(0.0, 0.0, 0.0), *, point=None, torque=(0.0, 0.0, 0.0),
                     frame: str = "world", duration: float = 0.0,
                     limits: CommandLimits = DEFAULT_LIMITS) -> WrenchCommand:
        """Apply ``force`` at ``point`` (None = the COM) plus the pure couple ``torque`` to ``body``.

        ``frame``: ``"world"`` (or ``""``) = world axes and world point; the body's name (or ``"body"``) =
        body axes with ``point`` relative to the COM.  ``duration``: 0 = next tick only, > 0 = that long
        (whole ticks, rounded up), < 0 = until :meth:`clear_wrenches`.  ``limits``: what a command may ask for.
        Raises ``WrenchError`` (a ValueError) naming the bad field."""
        frame = body if frame == "body" else frame
        command = make_command(self.body_model.names, body, force=force, torque=torque, point=point, frame=frame,
                               duration=duration, limits=limits, fixed=self.body_model.fixed,
                               positions=self.body_state.position)
        self.add_commands([command])
        return command

    def add_commands(self, commands: list[WrenchCommand]) -> int:
        """Schedule already-validated commands; returns how many fit under the active-wrench bound."""
        return self.wrenches.add(commands, self.dt)

    def clear_wrenches(self) -> None:
        self.wrenches.clear()

    # ---- editing while it runs: spawn, delete, teleport, query -------------------------------------------

    def entity_names(self, pattern: str = "") -> list[str]:
        """Bodies (in model order: a robot's links are bodies ``<robot>/<link>``), then flocks, then robots; with
        ``pattern``, those whose name it matches anywhere (a POSIX extended regular expression, see
        :func:`cgp_core.editing.name_filter`; ``ValueError`` if invalid)."""
        names = list(self.body_model.names) + [f.params.name for f in self.flocks] + self.robot_names()
        if not pattern:
            return names
        regex = name_filter(pattern)
        return [name for name in names if regex.search(name)]

    def entity_kind(self, name: str) -> str | None:
        """``"body"``, ``"flock"``, ``"robot"`` or None."""
        if name in self.body_model.names:
            return "body"
        if any(f.params.name == name for f in self.flocks):
            return "flock"
        return "robot" if name in self.robot_names() else None

    def entities_in_sphere(self, center, radius: float) -> list[str]:
        """Entities overlapping the ball of ``radius`` [m] around ``center`` (3,): bodies whose surface is within
        ``radius`` of it (exact shapes), flocks with a boid inside it (boids as spheres of ``boid_size``)."""
        center = check_vector(center, "center")
        d = body_distances(self.body_model, self.body_state, center)
        names = [name for name, di in zip(self.body_model.names, d) if di <= radius]
        for flock in self.flocks:
            gap = np.linalg.norm(flock.positions - center, axis=1) - 0.5 * flock.params.boid_size
            if gap.size and float(gap.min()) <= radius:
                names.append(flock.params.name)
        for robot in self.robot_names():  # a robot with a link within the ball
            if any(n.startswith(f"{robot}/") for n in names):
                names.append(robot)
        return names

    def unique_name(self, base: str) -> str:
        """``base`` if no entity has it, else ``base_2``, ``base_3``, ... (the first free one)."""
        return unique_name(base, set(self.entity_names()))

    def check_new_name(self, name: str) -> None:
        """:class:`EditError` (``name_invalid`` / ``name_taken``) unless ``name`` can name a new entity."""
        check_name(name)
        kind = self.entity_kind(name)
        if kind is not None:
            raise EditError("name_taken", f"name {name!r} is taken by a {kind}")

    def spawn(self, entry, *, name: str, position=(0.0, 0.0, 0.0), orientation=(0.0, 0.0, 0.0, 1.0),
              source: str = "<spawn>") -> str:
        """Add a body, a flock or a robot while the world runs; returns its kind (``"body"`` / ``"flock"`` /
        ``"robot"``).

        A robot: ``{"robot": {...}}``, a scene's ``robots`` entry without ``name``, ``position``, ``orientation``
        (the pose places its root link), ``urdf`` a file or ``urdf_xml`` URDF text; its links are appended as
        bodies ``<name>/<link>``, the robots already there keep their joint state, drives and commands
        (:meth:`cgp_core.robots.world.Robots.with_robot`).  See docs/robots.md.

        ``entry``: ``{"body": {...}}`` or ``{"flock": {...}}``, the entry a scene file's ``bodies`` / ``flocks``
        list holds (parsed YAML), without ``name`` and, for a body, without ``position`` / ``orientation``: those
        come from ``name`` and the pose (``position`` (3,), ``orientation`` (4,) xyzw; for a flock ``position``
        is the spawn centre and the orientation must be the identity).  The entry is validated as a scene is:
        :class:`~cgp_core.scene.SceneError` with the same texts, key paths from ``body`` / ``flock``.  Other
        refusals are :class:`~cgp_core.editing.EditError`.  A refused spawn changes nothing.

        A body comes last in the model, at rest unless the entry gives velocities; the bodies are woken (it
        may land on sleeping ones).  A flock starts from its seeded initial state around the centre.

        It is :meth:`prepare_spawn` (the costly part: validation, a flock's initial state) followed by
        :meth:`add_spawned`; a caller that must not wait for the first (the node) runs it on another thread."""
        return self.add_spawned(self.prepare_spawn(entry, name=name, position=position, orientation=orientation,
                                                   source=source, taken=set(self.entity_names())))

    def prepare_spawn(self, entry, *, name: str, taken: set[str], position=(0.0, 0.0, 0.0),
                      orientation=(0.0, 0.0, 0.0, 1.0), source: str = "<spawn>") -> PreparedSpawn:
        """Validate ``entry`` (see :meth:`spawn`) and build what the world will hold: a body's model and state
        rows, or a flock with its initial state.  Reads nothing of the world but its scene settings
        (:func:`prepare_spawn`, which a worker process runs with a copy of them); ``taken``: the names in use (a
        snapshot).  Raises as :meth:`spawn` does; :meth:`add_spawned` adds the result."""
        return prepare_spawn(entry, self.scene.world, name=name, taken=taken, position=position,
                             orientation=orientation, source=source)

    def add_spawned(self, prepared: PreparedSpawn) -> str:
        """Add what :meth:`prepare_spawn` built (between ticks, on the thread that steps); the name and the body
        limit are checked again (the world may have changed meanwhile).  Returns the kind."""
        self.check_new_name(prepared.name)
        if prepared.kind == "flock":
            boids = sum(len(f.positions) for f in self.flocks)
            if boids + len(prepared.flock.positions) > MAX_BOIDS:
                raise EditError("not_possible", f"the world has {boids} boids; with {len(prepared.flock.positions)} "
                                f"more it would pass the most it holds ({MAX_BOIDS}: cgp_core.limits)")
            self.flocks = [*self.flocks, prepared.flock]
            self._flock_mean_velocity_start.append(self.flocks[-1].mean_velocity())
        else:
            robots = None
            if prepared.kind == "robot":
                robots = self._robots_with(prepared.robot)  # refused here, before anything changes
            if self.body_model.count + prepared.model.count > MAX_BODIES:
                raise EditError("not_possible", f"the world has {self.body_model.count} bodies; with "
                                f"{prepared.model.count} more it would pass the most it holds ({MAX_BODIES})")
            (shapes, particles), (new_shapes, new_particles) = self.body_model.rigid_work(), prepared.model.rigid_work()
            refusal = rigid_work_refusal(shapes + new_shapes, particles + new_particles, self.substeps)
            if refusal:
                raise EditError("not_possible", f"with {prepared.name!r} the world would have {refusal}")
            model, state = prepared.model, prepared.state.copy()
            if self.body_state.rotation is not None:  # the integrator keeps R: the new body needs one too
                state.rotation = state.rotation_matrices()
            old_model = self.body_model
            if robots is not None:
                self._set_robots(robots)
                self.trajectories.start(robots, self.time_ns, names={prepared.name})  # its trajectory: from now
            self.body_model, self.body_state = concatenate_bodies(old_model, self.body_state, model, state)
            _, self._initial_body_state = concatenate_bodies(old_model, self._initial_body_state, model,
                                                             state.copy())
            self._bodies_changed()
            self._report_notes(prepared)
        self.spawned.append(prepared.name)
        self._info.pop(prepared.name, None)
        self.model_version += 1
        return prepared.kind

    def add_spawned_all(self, batch: list[PreparedSpawn]) -> list[str]:
        """Add every entity of ``batch`` or none (``simulation_interfaces``' SpawnEntities): the names are checked
        against the world and each other first; if one is refused while adding (a limit), those already added are
        removed again and the :class:`EditError` names the entry (``entry <k> (<name>): ...``; its ``entry``
        attribute is ``k``).  Returns the kinds."""
        names = [p.name for p in batch]
        for k, prepared in enumerate(batch):
            try:
                self.check_new_name(prepared.name)
                if prepared.name in names[:k]:
                    first = names.index(prepared.name)
                    raise EditError("name_taken", f"name {prepared.name!r} is also entry {first}'s")
            except EditError as exc:
                raise _entry_error(exc, k, prepared.name) from None
        added: list[str] = []
        kinds = []
        for k, prepared in enumerate(batch):
            try:
                kinds.append(self.add_spawned(prepared))
            except EditError as exc:
                if added:  # all or nothing: the batch's entities added so far go again
                    self._remove(added)
                raise _entry_error(exc, k, prepared.name) from None
            added.append(prepared.name)
        return kinds

    def delete(self, name: str) -> str:
        """Remove a body, a flock or a robot (from the scene or spawned); returns its kind.  A body's wrench
        commands go with it; the other bodies keep their order.  A robot goes with its links (and their wrench
        commands); the other robots keep their joint state, drives and commands.  :class:`EditError` ``unknown``
        if there is none."""
        kind = self.kind_of(name)
        if kind != "robot":
            self._refuse_link(name, "deleted")
        self._remove([name])
        return kind

    # ---- worlds: another scene into this running world ------------------------------------------------------

    def load(self, scene: str | Scene) -> None:
        """Replace everything in the world by ``scene`` (a scene file, a built-in name or a parsed :class:`Scene`):
        its bodies, flocks, robots, settings (gravity, integrator, ...) and named poses, its entities at their
        initial state; spawned entities and entity info go, wrench commands are dropped.  Time keeps running
        (``time_ns`` and ``ticks`` go on: clocks and recordings never go backwards); ``dt``, the caller's
        sub-steps and seed stay.  This very object changes (whoever holds the world keeps holding it), and
        ``model_version`` moves on.  Raises :class:`~cgp_core.scene.SceneError` (the scene's problems, or the
        sub-steps it would need) with the world unchanged: the new world is built completely before it
        replaces the old one.

        It is :meth:`prepare_load` (building the new world: the costly part, which may run on another thread
        while this world steps) followed by :meth:`adopt`."""
        self.adopt(self.prepare_load(scene))

    def prepare_load(self, scene: str | Scene) -> World:
        """A new world of ``scene`` with this world's ``dt``, sub-steps and seed, for :meth:`adopt`; reads nothing
        else of this world (another thread may build it while this one steps).  Raises as :meth:`load` does."""
        scene = scene if isinstance(scene, Scene) else load_scene(scene)
        return World(scene, dt=self.dt, substeps=self._substeps_arg, seed=self._seed)

    def unload(self) -> None:
        """An empty world (no bodies, flocks, robots or named poses; default settings, with the ground plane) that
        goes on stepping, so time keeps running; :attr:`loaded` is False until :meth:`load`."""
        self.adopt(self.prepare_load(Scene("<no world>", WorldSpec(), [], [])))
        self.loaded = False

    def adopt(self, other: World) -> None:
        """Become ``other`` (:meth:`prepare_load`'s world, not stepped since) but keep the clock, the counters and
        the caller's settings of this one (see :meth:`load`)."""
        kept = {"dt": self.dt, "dt_ns": self.dt_ns, "time_ns": self.time_ns, "ticks": self.ticks,
                "model_version": self.model_version + 1, "report_contacts": self.report_contacts}
        events = self.events + [WorldEvent(self.time, e.level, e.text) for e in other.events]
        self.__dict__.update(other.__dict__)
        self.__dict__.update(kept, events=events)
        self.loaded = True
        self.trajectories.start(self.robots, self.time_ns)  # the new scene's trajectories start now
        self.remember_tick_start()

    @property
    def named_poses(self) -> list:
        """The scene's named poses (:class:`cgp_core.scene.named_poses.NamedPoseSpec`), in file order."""
        return list(self.scene.named_poses)

    def named_pose(self, name: str):
        """The named pose ``name``; :class:`EditError` ``unknown`` (naming those there are) if none."""
        for pose in self.scene.named_poses:
            if pose.name == name:
                return pose
        known = [p.name for p in self.scene.named_poses]
        raise EditError("unknown", f"no named pose {name!r} (named poses: "
                        f"{', '.join(known[:20]) + (' ...' if len(known) > 20 else '') or 'none in this scene'})")

    # ---- what an entity is: info and bounds --------------------------------------------------------------------

    def entity_info(self, name: str) -> EntityInfo:
        """Its category, description and tags: what :meth:`set_entity_info` was told, else what it is (a robot
        and its links ``robot``, a flock ``dynamic_object``, a fixed body ``static_object``, any other body
        ``object``).  :class:`EditError` ``unknown`` if there is no such entity."""
        self.kind_of(name)
        if name in self._info:
            return self._info[name]
        return self._default_info([name])[name]

    def _default_info(self, names) -> dict[str, EntityInfo]:
        """What each of ``names`` (existing entities) is before anyone says otherwise, in one pass over the
        world (a filter over 10,000 bodies must not look each one up in the model's list)."""
        wanted, found = set(names), {}
        robots = self.robot_names()
        for robot in robots:
            if robot in wanted:
                found[robot] = EntityInfo("robot", f"robot, {len(self._robot_links(robot))} links with collision "
                                                   "geometry")
        for flock in self.flocks:
            if flock.params.name in wanted:
                found[flock.params.name] = EntityInfo("dynamic_object", f"flock of {len(flock.positions)} boids")
        robots = set(robots)
        for i, name in enumerate(self.body_model.names):
            if name in wanted:
                owner = name.split("/", 1)[0] if "/" in name else None
                found[name] = default_body_info(self.body_model, i, owner if owner in robots else None)
        return found

    def set_entity_info(self, name: str, category: str, description: str = "", tags=()) -> None:
        """Replace entity ``name``'s info (kept until it is deleted, or a spawned one is reset away, or another
        world is loaded).  :class:`EditError` ``unknown`` / ``invalid_info``; nothing changes then."""
        self.kind_of(name)
        self._info[name] = check_info(category, description, tags)

    def entities_with_info(self, names: list[str], categories=(), tags=(), match_all: bool = False) -> list[str]:
        """Those of ``names`` whose category is one of ``categories`` (none given: any) and whose tags pass
        ``tags`` (:func:`cgp_core.entities.tags_match`)."""
        if not categories and not tags:
            return list(names)
        defaults = self._default_info([n for n in names if n not in self._info])
        kept = []
        for name in names:
            info = self._info.get(name) or defaults[name]
            if (not categories or info.category in categories) and tags_match(info.tags, tags, match_all):
                kept.append(name)
        return kept

    def entity_bounds(self, name: str) -> tuple[np.ndarray, np.ndarray] | None:
        """``(lower, upper)`` (3,) each: the axis-aligned box that holds the entity, in the frame its
        :meth:`entity_state` gives (REP-103's canonical link): a body's own frame (its COM, its axes: from its
        shape, :func:`cgp_core.entities.body_frame_bounds`); a robot's root link frame, holding every link's
        box at the current joint positions; a flock's centroid with world axes, holding its boids.  None for a
        robot without collision geometry.  :class:`EditError` ``unknown`` if there is no such entity."""
        kind = self.kind_of(name)
        if kind == "flock":
            flock = self._flock(name)
            offsets = flock.positions - flock.centroid()
            half = 0.5 * flock.params.boid_size
            return offsets.min(axis=0) - half, offsets.max(axis=0) + half
        if kind == "body":
            return body_frame_bounds(self.body_model, self.body_model.names.index(name))
        links = [self.body_model.names.index(n) for n in self._robot_links(name)]
        if not links:
            return None
        R0, p0 = self._robot_root(name)[:2]
        R = self.body_state.rotation_matrices()
        corners = []
        for i in links:  # each link's box, its corners into the world and then into the root link's frame
            world = self.body_state.position[i] + box_corners(*body_frame_bounds(self.body_model, i)) @ R[i].T
            corners.append((world - p0) @ R0)
        points = np.concatenate(corners)
        return points.min(axis=0), points.max(axis=0)

    # ---- robots as entities ---------------------------------------------------------------------------------

    def robot_names(self) -> list[str]:
        """The URDF robots (scene or spawned) as entities: their names (a scene's ``joints:`` articulations are
        not entities: their bodies are)."""
        if self.robots is None:
            return []
        return [r.name for r in self.robots.robots if r.spec.articulation is None]

    def stop_trajectory(self, name: str) -> bool:
        """Stop robot ``name``'s scene trajectory (``robots[].trajectory``): its position drives hold the targets
        they were last given until a command comes.  The node calls it when a ``joint_commands`` or
        ``joint_trajectory`` message for the robot is applied (a ROS command wins); a ``Robots.command`` from
        Python between ticks stops it too (:class:`cgp_core.robots.trajectory.Following`).  A reset or a load
        starts it again.  Returns whether the robot was following one."""
        return self.trajectories.stop(name, self.robots)

    def _robots_with(self, spec):
        """The world's robots with ``spec``'s added (:meth:`Robots.with_robot`), or :class:`EditError`."""
        from .scene.robots import MAX_ROBOTS

        count = 0 if self.robots is None else len(self.robots.robots)
        if count + 1 > MAX_ROBOTS:
            raise EditError("not_possible", f"the world has {count} robots, the most it holds ({MAX_ROBOTS})")
        if spec.joint_integrator is None:  # a spawned robot without its own takes the world's
            from dataclasses import replace

            spec = replace(spec, joint_integrator=self.scene.world.joint_integrator)
        try:
            return Robots([spec]) if self.robots is None else self.robots.with_robot(spec)
        except ValueError as exc:  # MAX_ROBOT_DOFS
            raise EditError("not_possible", f"with robot {spec.name!r}: {exc}") from None

    def _set_robots(self, robots) -> None:
        """Replace :attr:`robots` (a robot added or removed): the islands start again, every body awake."""
        self.robots = robots
        self.sleep_enabled = bool(self.scene.world.sleep)
        self._islands = None

    def _robot_links(self, name: str) -> list[str]:
        prefix = f"{name}/"
        return [n for n in self.body_model.names if n.startswith(prefix)]

    def _robot_root(self, name: str):
        """Robot ``name``'s root link frame in the world and its velocity (of the frame's origin; ω in world axes):
        a :class:`~cgp_core.robots.algorithms.BodyMotion` of one body (rotation (3, 3), position, v, ω (3,))."""
        from .robots import algorithms

        robots = self.robots
        r = robots.robot(name)
        q, qd = robots.q[r.q_slice], robots.qd[r.dof_slice]
        rotation, position = algorithms.forward_kinematics(r.kernel_arrays, q)
        linear, angular = algorithms.body_velocities(r.kernel_arrays, q, qd, rotation, position)
        return algorithms.BodyMotion(rotation[0], position[0], linear[0], angular[0])

    def _set_robot_state(self, name: str, position, orientation, v, w) -> None:
        """Teleport a floating-base robot: its root link frame to ``position`` / ``orientation``, its root's twist
        (of the frame's origin, world axes) to ``v``, ``ω``; the joints keep their positions and velocities."""
        from .robots.model import JOINT_FLOATING

        r = self.robots.robot(name)
        if int(r.model.joint_type[0]) != JOINT_FLOATING:
            raise EditError("not_possible", f"{name} is a robot with a fixed base (welded to the world where it "
                            "was loaded or spawned): its state is its joints' (~/robots/<robot>/joint_commands); "
                            "to move its base, delete it and spawn it again at the new pose")
        q = self.robots.q[r.q_slice]
        q[0:3] = position
        q[3:7] = orientation
        qd = self.robots.qd[r.dof_slice]
        qd[0:3] = v
        qd[3:6] = w
        self.robots.write_bodies(self.body_model, self.body_state)
        rows = [self.body_model.names.index(n) for n in self._robot_links(name)]
        self.wake(rows)  # a sleeping robot would ignore the edit
        for start, now in zip(self._body_start, (self.body_state.linear_momentum, self.body_state.angular_momentum,
                                                 self.body_state.orientation)):
            start[rows] = now[rows]
        self.wake()

    def _refuse_link(self, name: str, what: str) -> None:
        """:class:`EditError` ``not_possible`` if body ``name`` is a robot's link (it moves by its joints)."""
        if self.robots is None:
            return
        i = self.body_model.names.index(name)
        group = self.robots.self_collision_group[i] if i < len(self.robots.self_collision_group) else -1
        if group >= 0:
            robot = self.robots.robots[group].name
            raise EditError("not_possible", f"{name} is a link of robot {robot}: it moves by its joints and cannot "
                            f"be {what} on its own")

    def _scene_bodies(self):
        """The scene's bodies, then the robots' links (:meth:`cgp_core.robots.world.Robots.body_specs`), as new
        model and state objects."""
        if self.robots is None:
            return self.scene.build_bodies()
        from dataclasses import replace

        return replace(self.scene, bodies=list(self.scene.bodies) + self.robots.body_specs()).build_bodies()

    def set_body_state(self, name: str, position, orientation, linear_velocity=(0.0, 0.0, 0.0),
                       angular_velocity=(0.0, 0.0, 0.0)) -> None:
        """Teleport a body: COM ``position`` (3,), ``orientation`` (4,) xyzw, and the world-frame twist it then
        has (the momenta are set from it: P = m v, L = I_world ω).  Wakes its island.  A fixed body takes a pose
        only (a non-zero twist is refused, as ``simulation_interfaces`` says for static objects).

        A robot: its root link frame's pose and twist (of the frame's origin); a floating-base robot only (a
        fixed base is refused, naming why: delete it and spawn it again elsewhere); the joints keep their state."""
        if self.entity_kind(name) == "robot":
            position, orientation = check_pose(position, orientation)
            v = check_vector(linear_velocity, "twist.linear", MAX_SPEED, "m/s")
            w = check_vector(angular_velocity, "twist.angular", MAX_SPIN, "rad/s")
            self._set_robot_state(name, position, orientation, v, w)
            return
        i = self._body_index(name)
        self._refuse_link(name, "teleported")
        position, orientation = check_pose(position, orientation)
        v = check_vector(linear_velocity, "twist.linear", MAX_SPEED, "m/s")
        w = check_vector(angular_velocity, "twist.angular", MAX_SPIN, "rad/s")
        model, state = self.body_model, self.body_state
        rim_speed = float(np.linalg.norm(v) + np.linalg.norm(w) * body_reach(
            model.shape[i], model.radius[i], model.half_extents[i]))
        if rim_speed > MAX_SPEED:
            raise EditError("invalid_pose", f"twist: {name}'s surface would move at up to {rim_speed:.4g} m/s "
                            f"(|v| + |ω| times its reach); at most {MAX_SPEED:g} m/s (what cgp_sim simulates: "
                            "cgp_core.limits)")
        if model.fixed[i] and (v.any() or w.any()):
            raise EditError("not_possible", f"{name} is fixed: it takes a pose, not a twist (got linear "
                            f"{v.tolist()}, angular {w.tolist()})")
        R = quat_to_matrix(orientation[None])[0]
        state.position[i] = position
        state.orientation[i] = orientation
        if state.rotation is not None:
            state.rotation[i] = R
        state.linear_momentum[i] = model.mass[i] * v * (not model.fixed[i])
        inertia = np.empty((3, 3))
        world_tensor(R, model.inertia_body[i], inertia)  # L = I_world ω
        state.angular_momentum[i] = np.array(tensor_times(inertia, w[0], w[1], w[2])) * (not model.fixed[i])
        for start, now in zip(self._body_start, (state.linear_momentum, state.angular_momentum,
                                                 state.orientation)):
            start[i] = now[i]  # a teleport is not an acceleration: this body's last-tick Δv starts from here
        self.wake([i])  # its island: a sleeping body would ignore the edit for collisions with other sleepers

    def move_flock(self, name: str, position) -> None:
        """Translate a flock rigidly so that its centroid is at ``position`` (3,): every boid moves by the
        same offset and keeps its velocity and frame.  A flock with bounds (``soft`` / ``wrap``) must stay
        inside them (:class:`EditError` ``not_possible`` otherwise)."""
        flock = self._flock(name)
        target = check_vector(position, "pose.position")
        if not (np.abs(target) <= MAX_COORDINATE).all():
            raise EditError("invalid_pose", f"pose.position must be within ±{MAX_COORDINATE:g} m on every axis "
                            f"(what cgp_sim simulates: cgp_core.limits), got {target.tolist()}")
        offset = target - flock.centroid()
        p = flock.params
        if p.bounds_mode != "none":
            low, high = flock.positions.min(axis=0) + offset, flock.positions.max(axis=0) + offset
            if np.any(low < p.bounds_min) or np.any(high > p.bounds_max):
                raise EditError("not_possible", f"flock {name} moved there would reach [{low.round(3).tolist()}, "
                                f"{high.round(3).tolist()}], outside its bounds [{p.bounds_min.tolist()}, "
                                f"{p.bounds_max.tolist()}]")
        flock.positions[:] += offset

    def entity_state(self, name: str) -> EntityState:
        """The state of a body, flock or robot (see :class:`~cgp_core.editing.EntityState`; a robot's is its root
        link frame's pose and twist — the velocity of the frame's origin, world axes — with zero accelerations)."""
        if self.entity_kind(name) == "robot":
            R, p, v, w = self._robot_root(name)
            zero = np.zeros(3)
            return EntityState("robot", p.copy(), matrix_to_quat(R[None])[0], v.copy(), w.copy(), zero, zero.copy())
        if self.entity_kind(name) == "flock":
            index = next(k for k, f in enumerate(self.flocks) if f.params.name == name)
            flock = self.flocks[index]
            v = flock.mean_velocity()
            zero = np.zeros(3)
            return EntityState("flock", flock.centroid(), np.array([0.0, 0.0, 0.0, 1.0]), v, zero,
                               (v - self._flock_mean_velocity_start[index]) / self.dt, zero.copy())
        i = self._body_index(name)
        model, state = self.body_model, self.body_state

        def velocities(P, L, R):  # v = P / m, ω = I_world⁻¹ L of body i alone (a query is O(1), not O(n))
            inv_inertia = np.empty((3, 3))
            world_tensor(np.ascontiguousarray(R), model.inv_inertia_body[i], inv_inertia)
            return P * model.inv_mass[i], np.array(tensor_times(inv_inertia, L[0], L[1], L[2]))

        R = state.rotation[i] if state.rotation is not None else quat_to_matrix(state.orientation[i][None])[0]
        v, w = velocities(state.linear_momentum[i], state.angular_momentum[i], R)
        P0, L0, q0 = (a[i] for a in self._body_start)
        v0, w0 = velocities(P0, L0, quat_to_matrix(q0[None])[0])
        return EntityState("body", state.position[i].copy(), state.orientation[i].copy(), v, w,
                           (v - v0) / self.dt, (w - w0) / self.dt)

    def kind_of(self, name: str) -> str:
        """``"body"``, ``"flock"`` or ``"robot"``; :class:`EditError` ``unknown`` (naming the entities there are)
        if none."""
        kind = self.entity_kind(name)
        if kind is None:
            known = self.entity_names()
            raise EditError("unknown", f"no body, flock or robot named {name!r} (entities: "
                            f"{', '.join(known[:20]) + (' ...' if len(known) > 20 else '') or 'none'})")
        return kind

    def _body_index(self, name: str) -> int:
        kind = self.kind_of(name)
        if kind != "body":
            raise EditError("not_possible", f"{name!r} is a {kind}, not a body")
        return self.body_model.names.index(name)

    def _flock(self, name: str) -> Flock:
        kind = self.kind_of(name)
        if kind != "flock":
            raise EditError("not_possible", f"{name!r} is a {kind}, not a flock")
        return next(f for f in self.flocks if f.params.name == name)

    def _remove(self, names: list[str]) -> None:
        """Delete these (existing) bodies, flocks and robots (with their links): new model and state without
        them."""
        robots = [n for n in names if self.entity_kind(n) == "robot"]
        for robot in robots:
            names = [*names, *self._robot_links(robot)]
            self._set_robots(self.robots.without(robot))
        gone = set(names)
        doomed = [i for i, n in enumerate(self.body_model.names) if n in gone]
        if doomed:
            keep = np.setdiff1d(np.arange(self.body_model.count), doomed)
            new_index = np.full(self.body_model.count, -1, dtype=np.intp)
            new_index[keep] = np.arange(len(keep))
            model = self.body_model
            self.body_model, self.body_state = select_bodies(model, self.body_state, keep)
            _, self._initial_body_state = select_bodies(model, self._initial_body_state, keep)
            self.wrenches.renumber_bodies(new_index)
            self._bodies_changed(keep)
        elif robots and self.robots is not None:  # a robot without collision geometry: no bodies of its own
            self.robots.attach(self.body_model)
        kept = [(f, v) for f, v in zip(self.flocks, self._flock_mean_velocity_start) if f.params.name not in gone]
        self.flocks = [f for f, _ in kept]
        self._flock_mean_velocity_start = [v for _, v in kept]
        self.spawned = [n for n in self.spawned if n not in gone]
        self._info = {n: info for n, info in self._info.items() if n not in gone}
        self.model_version += 1

    def _scene_names(self) -> list[str]:
        links = [] if self.robots is None else [n for n in self.body_model.names if "/" in n and
                                                 n.split("/", 1)[0] in self.robots.names()]
        robots = [s.name for s in self._scene_robot_specs if s.articulation is None]
        return [b.name for b in self.scene.bodies] + links + [p.name for p in self._scene_flock_params] + robots

    def _restore_scene(self) -> None:
        """The scene's bodies, flocks and robots, new objects (the states are reset by the caller)."""
        if self.robots is not None or self._scene_robot_specs:  # spawned robots go, deleted ones come back
            self._set_robots(Robots(self._scene_robot_specs) if self._scene_robot_specs else None)
        self.body_model, self._initial_body_state = self._scene_bodies()
        self.body_state = self._initial_body_state.copy()
        self.flocks = [Flock(p) for p in self._scene_flock_params]
        names, spawned = set(self.entity_names()), set(self.spawned)  # a scene entity keeps what it was told
        self._info = {n: info for n, info in self._info.items() if n in names and n not in spawned}
        self.spawned = []
        self.wrenches.clear()
        self.remember_tick_start()
        self._bodies_changed()
        self.model_version += 1

    def _bodies_changed(self, kept: np.ndarray | None = None) -> None:
        """After the body set changed (``kept``: the old indices that remain, None for a spawn: the new bodies
        are the last ones): derived arrays follow, and the bodies wake (a body may have appeared on, or vanished
        from under, sleeping ones): the islands are rebuilt for the new model with every body awake."""
        state = self.body_state
        if kept is not None:
            self._body_start = tuple(a[kept] for a in self._body_start)
        else:  # a new body starts its last-tick Δv from its spawn state; the others keep theirs
            known = len(self._body_start[0])
            self._body_start = tuple(np.concatenate((start, now[known:])) for start, now in zip(
                self._body_start, (state.linear_momentum, state.angular_momentum, state.orientation)))
        if hasattr(self.solver, "reset"):
            self.solver.reset()
        if self.robots is not None:
            self.robots.attach(self.body_model)
            self.solver.detector.exclude(*self.robots.exclusion)
        self.wake()

    def remember_tick_start(self) -> None:
        """Momenta and orientations at the start of the tick, for the accelerations :meth:`entity_state`
        reports (Δv / dt over the last tick); the flocks' mean velocities likewise."""
        state = self.body_state
        self._body_start = (state.linear_momentum.copy(), state.angular_momentum.copy(), state.orientation.copy())
        self._flock_mean_velocity_start = [flock.mean_velocity() for flock in getattr(self, "flocks", [])]

    # ---- views for publishers -------------------------------------------------------------------------

    def body_twist_in_body_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """Linear and angular velocity of every body in its own axes (the nav_msgs/Odometry convention):
        ``(v_body (n, 3), ω_body (n, 3))``."""
        state, model = self.body_state, self.body_model
        q_inv = quat_conjugate(state.orientation)
        return quat_rotate(q_inv, state.linear_velocity(model)), quat_rotate(q_inv, state.angular_velocity(model))

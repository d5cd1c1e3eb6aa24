"""The World: one scene's model and state, and the step pipeline.

``World.step()`` advances one *tick* of ``dt`` seconds (the node's ``1 / rate_hz``):

1. rigid bodies, unless they sleep: ``substeps`` sub-steps of ``h = dt / substeps``, each
   apply wrench commands → :func:`cgp_core.dynamics.step_bodies` (forces, contacts, solve, integrate,
   recover penetration, clear accumulators — the stages are named there);
2. contain blow-ups: a body whose state went non-finite or absurd is put back to its initial state (reported
   in :attr:`World.events`); the rest of the world goes on;
   then sleep: once every movable body has stayed slower than :data:`SLEEP_SPEED` for :data:`SLEEP_TIME`,
   the bodies fall asleep (momenta zeroed, stage 1 skipped) until a wrench command or :meth:`World.reset`
   wakes them (see :meth:`World._update_sleep`);
3. flocks: one step of ``dt`` each, avoiding the bodies at their end-of-tick poses (a flock whose state went
   non-finite is reset, and reported, the same way);
4. wrench schedule: count the tick off timed wrenches.

Usage (no ROS needed)::

    from cgp_core import World
    world = World.from_scene("default")
    world.apply_wrench("crate", force=[0, 0, 50], point=[0.2, 0, 0])   # world frame, for one tick
    for _ in range(60):
        world.step()
    print(world.time, world.body_state.position)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bodies import BodyModel, BodyState
from .boids import Flock, Obstacles
from .boids.predators import Predators
from .dynamics import Ground, step_bodies
from .integrators import make_integrator
from .rotation import quat_rotate, quat_conjugate
from .scene import Scene, load_scene
from .solver import make_solver
from .wrenches import WrenchCommand, WrenchSchedule, make_command

#: a body moving faster than this [m/s] or spinning faster than this [rad/s] has blown up numerically
BLOWUP_SPEED = 1e4
BLOWUP_SPIN = 1e5

#: Sleeping, as Box2D and Bullet do it: bodies at rest on each other cost a full contact solve per sub-step to
#: stay where they are.  A body is *resting* while the fastest point of its bounding sphere moves slower than
#: SLEEP_SPEED [m/s] (|v| + |ω| r, Box2D v3's measure and threshold); when every movable body has rested for
#: SLEEP_TIME [s] (Box2D's b2_timeToSleep) the bodies sleep.  The whole set sleeps or wakes together — one
#: island, where Box2D keeps one per connected contact group: simpler, and exact for what wakes it (only wrench
#: commands and reset can: boids steer around bodies but never push them).  A projectile at its apex is
#: slower than SLEEP_SPEED for a few milliseconds only, far less than SLEEP_TIME.  ``world.sleep: false`` in a
#: scene turns it off.
SLEEP_SPEED = 0.05
SLEEP_TIME = 0.5


@dataclass
class WorldEvent:
    """Something the world did on its own that a user should hear about (the node logs these)."""

    time: float
    level: str  # "warn" | "error"
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
    """

    def __init__(self, scene: Scene, *, dt: float = 1.0 / 60.0, substeps: int | None = None,
                 seed: int | None = None):
        self.scene = scene
        self.set_dt(dt)
        self.substeps = int(substeps if substeps is not None else scene.world.substeps)
        if self.substeps < 1:
            raise ValueError(f"substeps must be >= 1, got {self.substeps}")
        self.gravity = np.asarray(scene.world.gravity, dtype=float)
        self.ground = Ground(friction=scene.world.ground_friction,
                             restitution=scene.world.ground_restitution) if scene.world.ground else None
        self.integrator = make_integrator(scene.world.integrator)
        self.solver = make_solver(rolling_resistance=scene.world.rolling_resistance)
        self.body_model, self._initial_body_state = scene.build_bodies()
        self.body_state = self._initial_body_state.copy()
        self.flocks = [Flock(p if seed is None else p.with_seed(seed + i)) for i, p in enumerate(scene.flocks)]
        self.wrenches = WrenchSchedule()
        self.sleep_enabled = bool(scene.world.sleep)
        self._bounding_radius = self.body_model.bounding_radius()
        #: bodies marked ``predator: true`` (issue 14): every flock flees them
        self.predator_index = np.array([i for i, b in enumerate(scene.bodies) if b.predator], dtype=np.intp)
        #: True while the bodies sleep (stage 1 skipped); ``rest_time``: how long [s] all have been resting
        self.bodies_asleep = False
        self.rest_time = 0.0
        self.time_ns = 0
        self.ticks = 0
        self.events: list[WorldEvent] = []

    @classmethod
    def from_scene(cls, scene: str | Scene, **kwargs) -> "World":
        """A world from a scene file path, a built-in scene name, or a parsed :class:`Scene`."""
        return cls(scene if isinstance(scene, Scene) else load_scene(scene), **kwargs)

    # ---- stepping -------------------------------------------------------------------------------------

    def step(self) -> None:
        """Advance one tick (see the module docstring for the stages)."""
        h = self.dt / self.substeps
        model, state = self.body_model, self.body_state
        if self.bodies_asleep and self.wrenches.active:
            self.wake()
        if model.count and not self.bodies_asleep:
            # An extreme (but accepted) force can overflow a body's state to inf / NaN within the sub-steps;
            # numpy's warnings about it would only repeat, on stderr, what _contain_blowups reports right
            # after as an event naming the body.
            with np.errstate(over="ignore", invalid="ignore"):
                for _ in range(self.substeps):
                    self.wrenches.apply(state)
                    step_bodies(model, state, self.integrator, self.solver, h, gravity=self.gravity,
                                ground=self.ground, linear_damping=self.scene.world.linear_damping,
                                angular_damping=self.scene.world.angular_damping)
            self._update_sleep(*self._contain_blowups())
        if self.flocks:
            obstacles = Obstacles.from_bodies(model, state, ground=self.ground is not None) \
                if model.count or self.ground is not None else None
            predators = Predators.from_bodies(model, state, self.predator_index, self._bounding_radius) \
                if len(self.predator_index) else None
            for flock in self.flocks:
                flock.step(self.dt, obstacles, predators)
            self._contain_flock_blowups()
        self.wrenches.end_tick()
        self.ticks += 1
        self.time_ns += self.dt_ns

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
        names = ", ".join(model.names[i] for i in bad)
        self.events.append(WorldEvent(self.time, "error",
                                      f"numerical blow-up of {names} (non-finite or > {BLOWUP_SPEED:g} m/s): "
                                      "reset to its initial pose at rest and its wrenches cleared"))
        return speed, spin

    def _update_sleep(self, speed: np.ndarray, spin: np.ndarray) -> None:
        """Count how long every movable body has been resting (see :data:`SLEEP_SPEED`; ``speed`` = |v|,
        ``spin`` = |ω|, (n,) each); after :data:`SLEEP_TIME` put them to sleep with zero momenta, so they stay
        exactly where they rest."""
        model, state = self.body_model, self.body_state
        movable = ~model.fixed
        if not self.sleep_enabled or not movable.any():
            return
        fastest_point = speed + spin * self._bounding_radius
        if bool((fastest_point[movable] < SLEEP_SPEED).all()):
            self.rest_time += self.dt
        else:
            self.rest_time = 0.0
        if self.rest_time >= SLEEP_TIME - 1e-12:
            self.bodies_asleep = True
            state.linear_momentum[:] = 0.0
            state.angular_momentum[:] = 0.0

    def wake(self) -> None:
        """Wake the bodies (a wrench command or reset does it; call it after changing ``body_state`` by hand)."""
        self.bodies_asleep = False
        self.rest_time = 0.0

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

    def reset(self) -> None:
        """Back to the scene's initial state (bodies, flocks; wrenches cleared).  ``time`` keeps running."""
        self.body_state = self._initial_body_state.copy()
        for flock in self.flocks:
            flock.reset()
        self.wrenches.clear()
        self.wake()
        if hasattr(self.solver, "reset"):
            self.solver.reset()

    def apply_wrench(self, body: str, force=(0.0, 0.0, 0.0), *, point=None, torque=(0.0, 0.0, 0.0),
                     frame: str = "world", duration: float = 0.0, **limits) -> WrenchCommand:
        """Apply ``force`` at ``point`` (None = the COM) plus the pure couple ``torque`` to ``body``.

        ``frame``: ``"world"`` (or ``""``) = world axes and world point; the body's name (or ``"body"``) =
        body axes with ``point`` relative to the COM.  ``duration``: 0 = next tick only, > 0 = that long
        (whole ticks, rounded up), < 0 = until :meth:`clear_wrenches`.  Raises ``WrenchError`` (a ValueError)
        naming the bad field."""
        frame = body if frame == "body" else frame
        command = make_command(self.body_model.names, body, force=force, torque=torque, point=point, frame=frame,
                               duration=duration, fixed=self.body_model.fixed, positions=self.body_state.position,
                               **limits)
        self.add_commands([command])
        return command

    def add_commands(self, commands: list[WrenchCommand]) -> int:
        """Schedule already-validated commands; returns how many fit under the active-wrench bound."""
        return self.wrenches.add(commands, self.dt)

    def clear_wrenches(self) -> None:
        self.wrenches.clear()

    # ---- views for publishers -------------------------------------------------------------------------

    def body_twist_in_body_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """Linear and angular velocity of every body in its own axes (the nav_msgs/Odometry convention):
        ``(v_body (n, 3), ω_body (n, 3))``."""
        state, model = self.body_state, self.body_model
        q_inv = quat_conjugate(state.orientation)
        return quat_rotate(q_inv, state.linear_velocity(model)), quat_rotate(q_inv, state.angular_velocity(model))

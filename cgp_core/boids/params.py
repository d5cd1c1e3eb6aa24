"""Parameters of one boid flock (Reynolds 1987, the lecture's "Flocking" slides), with units and defaults.

The scene loader builds :class:`FlockParams` with keyword arguments, so the field names are the interface:
keep them stable.  Every value is checked in ``__post_init__``; a bad value raises ``ValueError`` naming the
field, the flock and what was expected.

Units: metres, seconds, degrees for the field of view.  The rule weights are *rates*, not the slides'
per-frame fractions (see ``rules.py``): cohesion and separation weights in 1/s², alignment in 1/s, so a
flock behaves the same at any tick rate.

The defaults give a flock that looks like a flock (or a school, with ``model='fish'``): 300 boids from a
random start align within ~5–10 s (polarization > 0.9) and swim as one calm group (~2 body lengths per
second) with neighbours just outside the separation radius (~17 within d), turning away from the walls of
the default 60 × 60 × 30 m box and around the world's bodies.  They were tuned (``benchmarks`` and the
sweeps behind them) for a flock that stays together from a random start while keeping the neighbour count,
which sets the cost of a step, moderate: a larger ``radius / separation_radius`` ratio holds flocks together
more easily but multiplies the neighbours by the cube of that ratio.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numpy as np

BOUNDS_MODES = ("soft", "wrap", "none")
MODELS = ("sphere", "fish")
NEIGHBOR_SEARCHES = ("grid", "kdtree", "brute")
# issue 14: the rule sets (``couzin.py``) and the neighbour modes (``topological.py``)
RULES = ("reynolds", "couzin")
NEIGHBOR_MODES = ("metric", "topological")


def _vec3(value, what: str) -> np.ndarray:
    try:
        array = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be 3 numbers [x, y, z], got {value!r}") from None
    if array.shape != (3,) or not np.all(np.isfinite(array)):
        raise ValueError(f"{what} must be 3 finite numbers [x, y, z], got {value!r}")
    return array


def _finite(value, what: str, *, minimum: float = 0.0, exclusive: bool = False) -> float:
    ok = isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)
    ok = ok and math.isfinite(value) and (value > minimum if exclusive else value >= minimum)
    if not ok:
        raise ValueError(f"{what} must be a finite number {'>' if exclusive else '>='} {minimum:g}, got {value!r}")
    return float(value)


@dataclass
class CouzinParams:
    """Couzin, Krause, James, Ruxton & Franks 2002 (J. theor. Biol. 218:1-11), the zonal model (``couzin.py``).

    Every field: unit, default (the paper's phase-figure values), meaning.  All rates are per second, so a
    flock behaves the same at any tick rate (see ``couzin.py`` for how the noise is scaled).

        repulsion_radius:   m, 1.0 — r_r: neighbours closer than this are avoided, with absolute priority.
        orientation_width:  m, 2.0 — Δr_o: neighbours at r_r <= d < r_r + Δr_o are aligned with.
        attraction_width:   m, 14.0 — Δr_a: neighbours at r_r + Δr_o <= d <= r_r + Δr_o + Δr_a attract.
        field_of_view_deg:  degrees, 270 — α, the field of perception: neighbours in the blind cone of
                            360 − α behind the animal are not perceived (by any zone).  360 = no blind volume.
        turning_rate_deg:   degrees per second, 40 — θ: the heading turns by at most θ·dt per tick.
        speed:              m/s, 3.0 — s: every animal always moves at this speed.
        noise:              rad, 0.05 — σ: standard deviation of the Gaussian angle by which the desired
                            direction is rotated, per paper time step τ = 0.1 s (``couzin.NOISE_TIME_STEP``).
    """

    repulsion_radius: float = 1.0
    orientation_width: float = 2.0
    attraction_width: float = 14.0
    field_of_view_deg: float = 270.0
    turning_rate_deg: float = 40.0
    speed: float = 3.0
    noise: float = 0.05

    def __post_init__(self) -> None:
        for name in ("repulsion_radius", "orientation_width", "attraction_width", "noise"):
            setattr(self, name, _finite(getattr(self, name), f"couzin.{name}"))
        for name in ("turning_rate_deg", "speed", "field_of_view_deg"):
            setattr(self, name, _finite(getattr(self, name), f"couzin.{name}", exclusive=True))
        if self.field_of_view_deg > 360.0:
            raise ValueError(f"couzin.field_of_view_deg must be in (0, 360], got {self.field_of_view_deg}")
        if self.perception_radius <= 0.0:
            raise ValueError("couzin: repulsion_radius + orientation_width + attraction_width must be > 0 (the "
                             "animals must perceive something)")

    @property
    def cos_half_fov(self) -> float:
        """cos(α / 2), what the zones' visibility test compares with (``rules.sees``); −1 for α = 360°: no
        blind cone, every neighbour is seen."""
        return math.cos(math.radians(0.5 * self.field_of_view_deg)) if self.field_of_view_deg < 360.0 else -1.0

    @property
    def perception_radius(self) -> float:
        """r_r + Δr_o + Δr_a: the outer edge of the zone of attraction [m]."""
        return self.repulsion_radius + self.orientation_width + self.attraction_width


@dataclass
class FlockParams:
    """One flock.  Every field: unit, default, meaning.

    Identity and spawn
        name:               str, "flock" — unique per world; used in topic / marker names.
        count:              int, 300 — number of boids N (>= 1).
        spawn_center:       (3,) m, (0, 0, 10) — centre of the box the boids start in.
        spawn_extent:       (3,) m, (12, 12, 6) — full size of that box (>= 0 each).  Positions are uniform
                            in it, directions uniform on the sphere, speeds uniform in [min_speed, max_speed].
        seed:               int, 0 — seeds the initial state (and a Couzin flock's noise, its own stream); a
                            Reynolds step uses no randomness: a flock is a deterministic function of (params,
                            dt sequence, obstacles, predators).

    Reynolds' rules (see ``rules.py`` for the formulas)
        radius:             m, 2.0 — neighbourhood radius d: boid j is a neighbour of i if |x_j − x_i| < d
                            (and j is inside i's field of view).
        separation_radius:  m, 1.0 — boids closer than this push each other apart (must be < radius).
        cohesion_weight:    1/s², 10.0 — w1: acceleration per metre of offset to the neighbours' centroid.
        separation_weight:  1/s², 300.0 — w2: acceleration per metre of intrusion into the separation radius
                            (stiff, so boids keep their distance; checked stable up to dt = 1/10 s, where
                            ``max_acceleration`` bounds it).
        alignment_weight:   1/s, 3.0 — w3: rate at which a boid's velocity relaxes to its neighbours' mean.
        fov_deg:            degrees, 270 — field of view, centred on the heading; neighbours in the blind
                            cone behind (360 − fov) are ignored by cohesion and alignment.  360 = no blind
                            angle.  Separation is felt all around (a fish's lateral line; boids do not ram
                            each other from behind).

    Motion limits
        min_speed:          m/s, 0.5 — boids never hover (> 0 keeps the heading, hence the frame, defined).
        max_speed:          m/s, 2.0.
        max_acceleration:   m/s², 20.0 — cap on the total steering acceleration (max turn rate at speed v
                            is max_acceleration / v).

    World
        bounds_min:         (3,) m, (−30, −30, 0.5) — lower corner of the world box.
        bounds_max:         (3,) m, (30, 30, 30.5) — upper corner.
        bounds_mode:        "soft" (default): walls push boids back inside within ``bounds_margin`` and a
                            boid never leaves the box; "wrap": periodic box (neighbourhoods wrap too; each
                            side must be longer than 2 · radius); "none": unbounded.
        bounds_margin:      m, 5.0 — soft walls start pushing this far inside the box.
        bounds_strength:    m/s², 10.0 — soft-wall acceleration at the wall (grows linearly across the margin).
        goal:               (3,) m or None, None — optional attractor point.
        goal_weight:        m/s², 1.0 — acceleration towards the goal (constant magnitude, so far boids are
                            not pulled harder than near ones).
        avoid_bodies:       bool, True — steer around the world's rigid bodies (and never enter them).
        obstacle_margin:    m, 2.0 — distance from a body's surface at which avoidance steering starts.
                            (The ground plane is an obstacle when the world has one: see ``Obstacles``.)

    Drawing and frames
        model:              "sphere" (default) | "fish" — what the markers draw.
        boid_size:          m, 0.3 — sphere diameter / fish length.  Bodies are inflated by half of it when
                            keeping boids out.
        bank_gain:          1, 1.0 — 0: the body stays level in turns; 1: banks like a coordinated turn
                            (dorsal axis along −gravity + centripetal acceleration).
        orientation_time_constant: s, 0.15 — low-pass time constant of the dorsal axis (no flips, no jitter).

    Implementation
        neighbor_search:    "grid" (default: cell-sorted uniform grid, the fast one) | "kdtree" (scipy
                            cKDTree) | "brute" (O(N²) reference).  All give the same neighbour sets.

    Rule sets, neighbours, predators (issue 14)
        rules:              "reynolds" (default: the lecture's rules above) | "couzin" (Couzin et al. 2002's
                            zonal model, ``couzin.py``, parameters in ``couzin``).  For a Couzin flock the
                            neighbourhood ``radius`` is set to r_r + Δr_o + Δr_a, ``min_speed`` and
                            ``max_speed`` to its speed s, and the Reynolds-only fields (weights,
                            separation_radius, fov_deg, goal) are unused (the scene loader rejects them).
                            ``max_acceleration`` is then the avoidance acceleration (walls, bodies,
                            predators) at which avoidance takes over the desired direction completely.
        couzin:             :class:`CouzinParams` (defaults: the paper's values) — used when rules is "couzin".
        neighbor_mode:      "metric" (default: every boid within the neighbourhood radius) | "topological"
                            (Ballerini et al. 2008: the ``neighbor_k`` nearest, at any distance, for every
                            rule, separation included; ``topological.py``).  Not with bounds_mode "wrap".
        neighbor_k:         int, 7 — the number of nearest neighbours in topological mode (>= 1).
        fright_radius:      m, 5.0 — a boid closer than this to a predator's surface (a body marked
                            ``predator: true``) flees it (``predators.py``): the escape is an avoidance
                            acceleration, so it has priority over cohesion and the other flocking rules.
    """

    name: str = "flock"
    count: int = 300
    spawn_center: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 10.0]))
    spawn_extent: np.ndarray = field(default_factory=lambda: np.array([12.0, 12.0, 6.0]))
    seed: int = 0
    radius: float = 2.0
    separation_radius: float = 1.0
    cohesion_weight: float = 10.0
    separation_weight: float = 300.0
    alignment_weight: float = 3.0
    fov_deg: float = 270.0
    min_speed: float = 0.5
    max_speed: float = 2.0
    max_acceleration: float = 20.0
    bounds_min: np.ndarray = field(default_factory=lambda: np.array([-30.0, -30.0, 0.5]))
    bounds_max: np.ndarray = field(default_factory=lambda: np.array([30.0, 30.0, 30.5]))
    bounds_mode: str = "soft"
    bounds_margin: float = 5.0
    bounds_strength: float = 10.0
    goal: np.ndarray | None = None
    goal_weight: float = 1.0
    avoid_bodies: bool = True
    obstacle_margin: float = 2.0
    model: str = "sphere"
    boid_size: float = 0.3
    bank_gain: float = 1.0
    orientation_time_constant: float = 0.15
    neighbor_search: str = "grid"
    rules: str = "reynolds"
    couzin: CouzinParams = field(default_factory=CouzinParams)
    neighbor_mode: str = "metric"
    neighbor_k: int = 7
    fright_radius: float = 5.0

    def __post_init__(self) -> None:
        where = f"flock {self.name!r}"
        # issue 14: a Couzin flock's neighbourhood radius and speeds follow from its zones and speed s
        if self.rules == "couzin":
            if not isinstance(self.couzin, CouzinParams):
                raise ValueError(f"{where}: couzin must be CouzinParams, got {type(self.couzin).__name__}")
            self.radius = self.couzin.perception_radius
            self.separation_radius = 0.5 * self.radius  # unused by the zonal model; keeps the check below
            self.min_speed = self.max_speed = self.couzin.speed
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"flock name must be a non-empty string, got {self.name!r}")
        if isinstance(self.count, bool) or not isinstance(self.count, (int, np.integer)) or self.count < 1:
            raise ValueError(f"{where}: count must be an integer >= 1, got {self.count!r}")
        self.count = int(self.count)
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"{where}: seed must be an integer >= 0, got {self.seed!r}")
        self.seed = int(self.seed)
        self.spawn_center = _vec3(self.spawn_center, f"{where}: spawn_center")
        self.spawn_extent = _vec3(self.spawn_extent, f"{where}: spawn_extent")
        if np.any(self.spawn_extent < 0.0):
            raise ValueError(f"{where}: spawn_extent must be >= 0 on every axis, got {self.spawn_extent.tolist()}")
        self.bounds_min = _vec3(self.bounds_min, f"{where}: bounds_min")
        self.bounds_max = _vec3(self.bounds_max, f"{where}: bounds_max")
        if self.goal is not None:
            self.goal = _vec3(self.goal, f"{where}: goal")

        def positive(name: str, allow_zero: bool = False) -> None:
            value = getattr(self, name)
            ok = isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)
            ok = ok and math.isfinite(value) and (value >= 0.0 if allow_zero else value > 0.0)
            if not ok:
                raise ValueError(f"{where}: {name} must be a finite number {'>= 0' if allow_zero else '> 0'}, "
                                 f"got {value!r}")
            setattr(self, name, float(value))

        for name in ("radius", "separation_radius", "min_speed", "max_speed", "max_acceleration", "boid_size"):
            positive(name)
        for name in ("cohesion_weight", "separation_weight", "alignment_weight", "bounds_margin",
                     "bounds_strength", "goal_weight", "obstacle_margin", "bank_gain",
                     "orientation_time_constant", "fright_radius"):
            positive(name, allow_zero=True)
        positive("fov_deg")
        if self.fov_deg > 360.0:
            raise ValueError(f"{where}: fov_deg must be in (0, 360], got {self.fov_deg}")
        if self.separation_radius >= self.radius:
            raise ValueError(f"{where}: separation_radius ({self.separation_radius}) must be smaller than "
                             f"radius ({self.radius})")
        if self.min_speed > self.max_speed:
            raise ValueError(f"{where}: min_speed ({self.min_speed}) must not exceed max_speed ({self.max_speed})")
        for name, allowed in (("bounds_mode", BOUNDS_MODES), ("model", MODELS),
                              ("neighbor_search", NEIGHBOR_SEARCHES), ("rules", RULES),
                              ("neighbor_mode", NEIGHBOR_MODES)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{where}: {name} must be one of {', '.join(allowed)}; got {getattr(self, name)!r}")
        if isinstance(self.neighbor_k, bool) or not isinstance(self.neighbor_k, (int, np.integer)) \
                or self.neighbor_k < 1:
            raise ValueError(f"{where}: neighbor_k must be an integer >= 1, got {self.neighbor_k!r}")
        self.neighbor_k = int(self.neighbor_k)
        if self.neighbor_mode == "topological" and self.bounds_mode == "wrap":
            raise ValueError(f"{where}: neighbor_mode 'topological' does not support bounds_mode 'wrap' (the k "
                             "nearest may lie beyond the periodic images); use soft walls or none")
        for name in ("avoid_bodies",):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{where}: {name} must be true or false, got {getattr(self, name)!r}")
        if self.bounds_mode != "none":
            size = self.bounds_max - self.bounds_min
            if np.any(size <= 0.0):
                raise ValueError(f"{where}: bounds_max must exceed bounds_min on every axis, got "
                                 f"min {self.bounds_min.tolist()} max {self.bounds_max.tolist()}")
            if self.bounds_mode == "wrap" and np.any(size <= 2.0 * self.radius):
                raise ValueError(f"{where}: with bounds_mode 'wrap' every side of the box must be longer than "
                                 f"2 * radius = {2.0 * self.radius}; got sizes {size.tolist()}")
            lo = self.spawn_center - 0.5 * self.spawn_extent
            hi = self.spawn_center + 0.5 * self.spawn_extent
            if np.any(lo < self.bounds_min) or np.any(hi > self.bounds_max):
                raise ValueError(f"{where}: the spawn box [{lo.tolist()}, {hi.tolist()}] must lie inside the "
                                 f"bounds [{self.bounds_min.tolist()}, {self.bounds_max.tolist()}]")

    @property
    def cos_half_fov(self) -> float:
        """cos(fov / 2): j is visible to i when v̂_i · (x_j − x_i) > cos_half_fov · |x_j − x_i|."""
        return math.cos(math.radians(0.5 * self.fov_deg))

    def with_seed(self, seed: int) -> FlockParams:
        """A copy with another seed (validated again)."""
        return replace(self, seed=seed)

    @classmethod
    def field_names(cls) -> list[str]:
        """The keyword arguments the constructor accepts (for the scene loader's unknown-key errors)."""
        return [f.name for f in fields(cls)]

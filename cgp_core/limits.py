"""Every limit on what users give cgp_sim, in one place (docs/scenes.md "Limits" is this file in prose).

Two kinds:

- **Caps on size and count**, checked *before* the cost is paid: a file's bytes before it is read, a string's
  bytes before it is parsed, YAML's nesting depth and node count while its events are read (before anything is
  built), list lengths before arrays are built.  They keep every request's time and memory bounded.
- **Ranges of the physical quantities** the simulation can hold.  float64 holds 1e±308, but a body is a mass
  and an inertia (m L², and its inverse), momenta (m v) and contacts whose tolerances are fixed lengths
  (:data:`cgp_core.collision.detector.DEFAULT_SPECULATIVE_DISTANCE` 2 mm, the box–box tolerance 5e-5 m): the
  ranges below keep every derived quantity many orders of magnitude inside float64 (m L² ≥ 1e-12, its inverse
  ≤ 1e12; m v ≤ 1e12 ...) and every length well above the contact tolerances, so that an accepted value is one
  the solver can simulate, never one that overflows or is reset as a "numerical blow-up" at once.  A value
  outside is refused with the field's name and the range.

ROS-free and dependency-free: the node, the scene loader and the readers of :mod:`cgp_core.user_input` import it.
"""

from __future__ import annotations

# ---- sizes and counts ---------------------------------------------------------------------------------------

#: bytes of a file read as a scene, a spawn ``uri`` or any other user file (checked before reading; the read
#: itself is bounded too, for files that grow or lie about their size)
MAX_FILE_BYTES = 16 * 1024 * 1024
#: bytes of YAML text parsed from a string (a spawn request's ``resource_string``), checked before parsing
MAX_YAML_BYTES = MAX_FILE_BYTES
#: YAML nesting depth (collections inside collections).  A scene needs 5 (bodies → body → particles → row);
#: deeper documents are refused while their events are read, before anything recursive runs
MAX_YAML_DEPTH = 32
#: YAML nodes (scalars + collections) of one document, counted while its events are read: a 100,000-particle
#: body is ~500,000 nodes
MAX_YAML_NODES = 1_000_000
#: body / flock names become parts of topic names (``~/bodies/<body>/odom``), which DDS limits in length
MAX_NAME_LENGTH = 64
MAX_BODIES = 10_000
#: boids of one flock, and of all flocks of a world together.  Issue 27 measured a million-boid flock (at a density
#: within MAX_EXPECTED_NEIGHBORS) at ~1.8 s per step in-process on 2 cores, before its 56 MB of poses per tick
#: are published and recorded: the node answers requests only between ticks.  100,000 boids step in ~0.2 s.
MAX_BOIDS_PER_FLOCK = 100_000
MAX_BOIDS = 200_000
#: the brute-force neighbour search (neighbor_search: brute, the O(N²) reference) is for small flocks only:
#: 40,000 boids took 8-20 s a step
MAX_BOIDS_BRUTE = 5_000
#: particles of one particle body: 100,000 step in ~0.2 s (on the ground or in the air) since the broad phase
#: skips a body's own particles (cgp_core.collision.broadphase.sweep_and_prune_kernel)
MAX_PARTICLES_PER_BODY = 100_000
#: a flock's expected neighbours per boid, N · (4/3)π r³ / V, at its spawn density (V: the spawn box, each side
#: at least 2 r) and, with walls (soft / wrap bounds), at the density of its bounds box: the work of a flock
#: step is N times this.  The default flock has ~12 at spawn; a million boids in the default 12 × 12 × 6 m
#: spawn box would have ~39,000 each (4·10¹⁰ pairs a tick: the node would never tick)
MAX_EXPECTED_NEIGHBORS = 256
#: a user's regular expression (the entity filter), in characters
MAX_PATTERN_LENGTH = 1024
#: issue 25's shapes.  Points a convex hull is taken of (qhull is O(n log n); a body's hull needs far fewer), and
#: vertices of the hull (every query on a hull — GJK, SAT, clipping — grows with them: simplify the shape)
MAX_HULL_POINTS = 100_000
MAX_HULL_VERTICES = 1024
#: a mesh file's bytes (a binary STL of ~670k triangles; checked before reading, :mod:`cgp_core.user_input`),
#: and its vertices and triangles after equal vertices are merged (a static mesh's BVH of 500k triangles builds in
#: ~0.2 s and holds ~45 MB)
MAX_MESH_FILE_BYTES = 32 * 1024 * 1024
MAX_MESH_VERTICES = 500_000
MAX_MESH_TRIANGLES = 500_000
#: the mesh files one scene or one spawn request reads, together, in bytes (each file counted once, by its size,
#: before it is read): parsing costs ~1 s per 30 MB (issue 38: a compound body's 256 parts could each name a
#: different 32 MB file)
MAX_MESH_BYTES_PER_REQUEST = 4 * MAX_MESH_FILE_BYTES
#: parts of one compound body (each is a collision primitive of its own)
MAX_PARTS_PER_BODY = 256
#: a tick's rigid-body work, which grows with the sub-steps (``world.substeps``, the node's ``substeps``): issue 27
#: measured 10,000 bodies × 1,000 sub-steps at minutes a tick, inside every other limit.  Two products are
#: bounded, checked when a scene is loaded, when a world is made with its own sub-steps and when a body is
#: spawned (:func:`rigid_work_refusal`):
#:
#: - sub-steps × *shapes*: a body is one shape, a compound body one per part (the solver, the integrator and
#:   the narrow phase work per shape).  40,000 = 10,000 bodies at the default 4 sub-steps, or 40 bodies at the
#:   most sub-steps (1,000).  Measured (speed probe python 15-23 ms, a slow phase): 10,000 spheres in a 22³ pile
#:   at 4 sub-steps 0.45-0.63 s a tick; 2,000 compound bodies of 16 parts at 4 sub-steps (128,000: refused)
#:   0.58 s.
#: - sub-steps × *particles* (of every particle body together): 400,000 = a 100,000-particle body at 4
#:   sub-steps, 0.12 s a tick; a particle costs the broad phase and the ground contact only.
MAX_SHAPE_SUBSTEPS = 40_000
MAX_PARTICLE_SUBSTEPS = 400_000

# ---- ranges of physical quantities --------------------------------------------------------------------------

#: lengths [m]: radii, box sizes, capsule lengths, particle radii and offsets, flock radii.  1 mm is 20x the
#: box–box contact tolerance; 10 km bodies keep m L² and contact lever arms far inside float64
MIN_LENGTH, MAX_LENGTH = 1e-3, 1e4
#: any coordinate [m] (positions, flock spawn boxes, bounds, goals): float64's spacing at 1e6 m is 1.2e-10 m,
#: 5 orders below the contact tolerances
MAX_COORDINATE = 1e6
#: masses [kg] (a body's, a particle's, a particle body's total): a milligram to a million tonnes
MIN_MASS, MAX_MASS = 1e-6, 1e9
#: densities [kg/m³] (the resulting mass must be within [MIN_MASS, MAX_MASS] too)
MIN_DENSITY, MAX_DENSITY = 1e-3, 1e6
#: a body moving faster than this [m/s] or spinning faster than this [rad/s] has blown up numerically: the World
#: resets it (:meth:`cgp_core.world.World.step`)
BLOWUP_SPEED = 1e4
BLOWUP_SPIN = 1e5
#: speeds a user may give [m/s] (initial and set velocities, boid speeds): a tenth of the blow-up threshold,
#: so an accepted state is never reset as a blow-up by itself
MAX_SPEED = BLOWUP_SPEED / 10
#: angular speeds a user may give [rad/s]
MAX_SPIN = BLOWUP_SPIN / 10
#: |gravity| [m/s²]: about 100 g
MAX_GRAVITY = 1e3
#: accelerations of flock rules [m/s²] (max_acceleration, walls, goal)
MAX_ACCELERATION = 1e4
#: viscous damping rates [1/s] (world.linear_damping / angular_damping): a 10 ms time constant; damping is a
#: force, so c · h must stay below 2 (h = dt / substeps: 60 Hz with 1 substep is c ≤ 120)
MAX_DAMPING = 1e2
#: Coulomb friction coefficients μ (a body's, the ground's)
MAX_FRICTION = 10.0
#: rolling resistance c_rr
MAX_ROLLING_RESISTANCE = 1.0
#: the smallest principal moment of inertia of a body over its largest: a 1 cm x 10 m pole has ~2e-6.  Found by
#: issue 27's fuzzing: a 1 mm x 1 mm x 10 km box (ratio ~1e-14) spinning at 8,700 rad/s blew up in its first
#: tick (ω = I⁻¹ L loses every digit of the thin axis).  Particle bodies also keep inertia.SINGULAR_INERTIA_RTOL.
MIN_INERTIA_RATIO = 1e-6
#: any other number of a scene (rule weights, gains, time constants) in magnitude
MAX_MAGNITUDE = 1e6
#: joint velocities of one robot: each robot's joint-space step factors its own dense (n, n) matrix every sub-step
#: (O(n³): 64 dofs ~0.1 ms); robots are solved one by one, so a world's robots are bounded by MAX_BODIES (their
#: links) and the tick's work, not by this.  Robots whose links touch in a sub-step are solved together (their
#: dofs summed: a pile of arms pays the cube of the pile's dofs)
MAX_ROBOT_DOFS = 64


def rigid_work_refusal(shapes: int, particles: int, substeps: int) -> str | None:
    """Why a world of ``shapes`` shapes and ``particles`` particles (see :data:`MAX_SHAPE_SUBSTEPS`) may not step
    ``substeps`` sub-steps a tick; None if it may."""
    if shapes * substeps > MAX_SHAPE_SUBSTEPS:
        return (f"{shapes:,} shapes (bodies, a compound body's parts) × {substeps:,} sub-steps = "
                f"{shapes * substeps:,} a tick; at most {MAX_SHAPE_SUBSTEPS:,} (cgp_core.limits: a tick's work)")
    if particles * substeps > MAX_PARTICLE_SUBSTEPS:
        return (f"{particles:,} particles × {substeps:,} sub-steps = {particles * substeps:,} a tick; at most "
                f"{MAX_PARTICLE_SUBSTEPS:,} (cgp_core.limits: a tick's work)")
    return None

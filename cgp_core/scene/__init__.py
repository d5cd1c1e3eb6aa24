"""Scenes: YAML files (YAML's safe subset only) describing a world, its rigid bodies and its boid flocks.

A scene is validated completely before anything is built: every error names the file, the key path (e.g.
``bodies[2].size``) and what is wrong, and all errors of a file are reported together.  Parsing uses
PyYAML's ``SafeLoader`` (plain data only: a ``!!python/...`` tag is an error, never executed) with one
addition: a key given twice in one mapping is an error, not silently "the last one wins".  The format
(SI units, frame ``world``, z up as REP-103):

.. code-block:: yaml

    world:
      gravity: [0, 0, -9.81]          # m/s²
      ground: true                     # static plane z = 0
      ground_friction: 0.6             # Coulomb μ of the ground (combined with the body's, see cgp_core.solver)
      ground_restitution: 0.0          # e of the ground
      integrator: implicit_midpoint    # explicit_euler | symplectic_euler | rk4 | implicit_midpoint
      substeps: 4                      # physics sub-steps per tick (the node's `substeps` overrides)
      contact_detection: every_substep # | once_per_tick: a tick's first sub-step's contacts carried through the
                                       # others while nothing moves (cgp_core.collision.carry)
      linear_damping: 0.0              # 1/s
      angular_damping: 0.0             # 1/s
      rolling_resistance: 0.01         # c_rr of every contact: a rolling ball slows at (5/7) c_rr g
      sleep: true                      # bodies sleep once all of them rest (see cgp_core.world.SLEEP_SPEED)
    bodies:
      - name: crate                    # unique, ROS-name-safe ([A-Za-z][A-Za-z0-9_]*)
        shape: box                     # sphere | box | capsule | particles | convex | compound | mesh
        size: [0.4, 0.4, 0.4]          # box: full extents [m]
        # radius: 0.2                  # sphere, capsule; particles: the radius each particle collides with
        # length: 0.5                  # capsule: length of the axis segment (body z), without the caps
        # particles: [[x, y, z, m], ...]  # particles: body-frame positions [m] and masses [kg]
        mass: 2.0                      # kg — or density: kg/m³ (not for particles: masses are per particle)
        position: [0, 0, 2]            # world position of the body origin (the COM; for particles the origin
                                       # of the particle coordinates, the COM is computed from them)
        orientation: [0, 0, 0, 1]      # quaternion x, y, z, w (normalized on load)
        linear_velocity: [0, 0, 0]     # m/s, world
        angular_velocity: [0, 0, 0]    # rad/s, world
        restitution: 0.3
        friction: 0.5
        fixed: false                   # immovable (walls, ramps, obstacles)
        predator: false                # boids of every flock flee it (cgp_core.boids.predators)
        color: [0.8, 0.3, 0.2, 1.0]    # RGBA for markers
      - name: rock                     # issue 25: a convex polyhedron, the hull of points or of a mesh file
        shape: convex
        mesh: rock.stl                 # .stl / .obj: from the scene file's directory, else the built-in meshes
        # points: [[x, y, z], ...]     # ... or the points whose hull it is (>= 4, not coplanar)
        scale: 1.0                     # optional: a factor, or [sx, sy, sz], applied to the points / the mesh
        density: 2600
      - name: table                    # one rigid body made of parts (mass spread over them by volume)
        shape: compound
        parts:
          - {shape: box, size: [1.0, 0.6, 0.04], position: [0, 0, 0.4]}
          - {shape: capsule, radius: 0.03, length: 0.38, position: [0.45, 0.25, 0.19]}
          - {shape: convex, points: [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]], orientation: [0, 0, 0, 1]}
        mass: 8.0
      - name: terrain                  # a static triangle mesh (fixed bodies only), with a BVH
        shape: mesh
        mesh: terrain.obj
        fixed: true
        # two_sided: false             # true: its triangles push from both sides (default: from the front)
    flocks:
      - name: fish
        count: 300
        spawn: {center: [0, 0, 4], extent: [8, 8, 3]}
        radius: 2.0
        separation_radius: 0.6
        weights: {cohesion: 0.6, separation: 2.0, alignment: 1.0}
        min_speed: 1.0
        max_speed: 4.0
        model: fish                    # sphere | fish
        seed: 1
        # ... and the optional keys of cgp_core.boids.FlockParams (field of view, bounds, goal, ...)
        neighbors: {mode: metric, k: 7}   # metric | topological (the k nearest, at any distance)
        fright_radius: 5.0             # flee predators closer than this to their surface [m]
      - name: school                   # Couzin et al. 2002's zonal model (cgp_core.boids.couzin)
        count: 100
        rules: couzin                  # reynolds (default) | couzin
        couzin: {repulsion_radius: 1.0, orientation_width: 2.0, attraction_width: 14.0,
                 field_of_view_deg: 270.0, turning_rate_deg: 40.0, speed: 3.0, noise: 0.05}
        spawn: {center: [0, 0, 20], extent: [10, 10, 10]}
        bounds: {mode: none}

The package, one file per part of that: :mod:`.validation` (``SceneError``, the ``Validator`` every part checks
its keys with), :mod:`.specs` (the parsed scene as plain data), :mod:`.loading` (finding and reading a scene,
the ``world`` block, spawn entries), :mod:`.bodies` (``bodies`` entries and the closed-form shapes),
:mod:`.particles` (the particle set), :mod:`.shapes` (issue 25's convex, compound and mesh shapes),
:mod:`.mesh_files` (the mesh files they read: once per request, their numbers held to the scene's ranges after
the scale) and :mod:`.flocks` (``flocks`` entries).
"""

from .bodies import body_reach
from .flocks import flock_crowding
from .loading import (
    MAX_SCENE_BYTES,
    SPAWN_KINDS,
    Gallery,
    _SceneLoader,
    available_scenes,
    builtin_scene_dir,
    builtin_scene_names,
    load_scene,
    parse_scene,
    parse_yaml,
    resolve_scene,
    scene_description,
    scene_from_dict,
    scene_identity,
    spawn_entry,
    spawnable_files,
)
from .mesh_files import builtin_mesh_dir
from .named_poses import NamedPoseBounds, NamedPoseSpec
from .shapes import compound_half_extents
from .specs import BodySpec, Scene, WorldSpec
from .validation import COORDINATES, GROUND_NAME, LENGTHS, MAX_REPORTED_PROBLEMS, ROS_SAFE_NAME, SceneError, Validator

__all__ = [
    "COORDINATES", "GROUND_NAME", "LENGTHS", "MAX_REPORTED_PROBLEMS", "MAX_SCENE_BYTES", "ROS_SAFE_NAME",
    "SPAWN_KINDS", "BodySpec", "Gallery", "NamedPoseBounds", "NamedPoseSpec", "available_scenes", "scene_identity",
    "spawnable_files", "Scene", "SceneError", "Validator", "WorldSpec", "body_reach", "builtin_mesh_dir",
    "builtin_scene_dir", "builtin_scene_names", "compound_half_extents", "flock_crowding", "load_scene",
    "parse_scene", "parse_yaml", "resolve_scene", "scene_description", "scene_from_dict", "spawn_entry", "_SceneLoader",
]

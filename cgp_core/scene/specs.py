"""The parsed scene: plain data, validated, SI units (:class:`WorldSpec`, :class:`BodySpec`, :class:`Scene`),
and the keys a body entry takes by shape.  Building arrays from it is :meth:`Scene.build_bodies` (and World's)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..bodies import BodyModel, BodyState, CompoundParts, Shape, rigid_work
from ..integrators import DEFAULT_INTEGRATOR
from ..robots.joint_integrators import DEFAULT_JOINT_INTEGRATOR

#: ``world.contact_detection``'s values: contacts found every sub-step (the default), or once per tick and carried
#: through its sub-steps while nothing moves (cgp_core.collision.carry)
CONTACT_DETECTION = ("every_substep", "once_per_tick")


@dataclass
class WorldSpec:
    gravity: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    ground: bool = True
    ground_friction: float = 0.6
    ground_restitution: float = 0.0
    integrator: str = DEFAULT_INTEGRATOR
    substeps: int = 4
    #: ``every_substep`` (default) or ``once_per_tick``: the contacts found at a tick's first sub-step carried
    #: through the others while no body moved by more than 1 mm (cgp_core.collision.carry)
    contact_detection: str = "every_substep"
    linear_damping: float = 0.0
    angular_damping: float = 0.0
    #: c_rr of every contact (cgp_core.solver.SolverSettings.rolling_resistance): 0.01, a rubber tyre on
    #: asphalt or a wooden ball on wood, so balls and logs come to rest; 0 is the ideal rigid model
    rolling_resistance: float = 0.01
    sleep: bool = True
    #: the joint-space integrator of every robot and scene articulation (a robot entry's own
    #: ``joint_integrator`` wins): cgp_core.robots.joint_integrators.JOINT_INTEGRATORS
    joint_integrator: str = DEFAULT_JOINT_INTEGRATOR


@dataclass
class BodySpec:
    name: str
    shape: Shape
    mass: float
    inertia_body: np.ndarray  # (3, 3) about the COM, body axes
    radius: float = 0.0
    half_extents: np.ndarray = field(default_factory=lambda: np.zeros(3))
    particles: np.ndarray | None = None  # (k, 4) body frame about the COM
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))  # COM, world
    orientation: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))
    linear_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    restitution: float = 0.3
    friction: float = 0.5
    fixed: bool = False
    color: np.ndarray = field(default_factory=lambda: np.array([0.7, 0.7, 0.75, 1.0]))
    predator: bool = False  # boids flee it (issue 14, cgp_core.boids.predators)
    hull: Any = None  # CONVEX: cgp_core.collision.convex.ConvexPolyhedron about the COM
    parts: CompoundParts | None = None  # COMPOUND
    mesh: Any = None  # MESH: cgp_core.collision.bvh.StaticMesh
    two_sided: bool = False  # MESH
    #: what loading it had to say, as (level, text): "warn" (points inside a hull), "info" (a BVH's build
    #: time and memory); World turns them into events
    notes: list = field(default_factory=list)


@dataclass
class Scene:
    source: str
    world: WorldSpec
    bodies: list[BodySpec]
    flocks: list[Any]  # cgp_core.boids.FlockParams
    robots: list[Any] = field(default_factory=list)  # cgp_core.scene.robots.RobotSpec (issue 35)
    joints: list[Any] = field(default_factory=list)  # cgp_core.scene.joints.JointSpec (issue 35)
    #: the articulations the joints make, as robots whose links are the scene's bodies (RobotSpec)
    articulations: list[Any] = field(default_factory=list)
    #: the poses the scene names (cgp_core.scene.named_poses.NamedPoseSpec), and its ``description:`` text
    named_poses: list[Any] = field(default_factory=list)
    description: str = ""
    #: the scene's ``tags:`` (simulation_interfaces' world tags: get_available_worlds filters on them)
    tags: tuple[str, ...] = ()

    def rigid_work(self) -> tuple[int, int]:
        """``(shapes, particles)`` of the bodies, the counts a tick's work is bounded by
        (:func:`cgp_core.limits.rigid_work_refusal`)."""
        return rigid_work([b.parts for b in self.bodies], [b.particles for b in self.bodies])

    def build_bodies(self) -> tuple[BodyModel, BodyState]:
        """Static model and initial state arrays of the bodies (see cgp_core.bodies for every shape)."""
        n = len(self.bodies)
        if n == 0:
            return BodyModel.empty(), BodyState(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros((0, 3)))
        mass = np.array([b.mass for b in self.bodies])
        fixed = np.array([b.fixed for b in self.bodies])
        inertia = np.stack([b.inertia_body for b in self.bodies])
        inv_mass = np.where(fixed, 0.0, 1.0 / np.where(fixed, 1.0, mass))  # (a static mesh has no mass)
        inv_inertia = np.linalg.inv(inertia)
        inv_inertia[fixed] = 0.0
        model = BodyModel(
            names=[b.name for b in self.bodies],
            shape=np.array([int(b.shape) for b in self.bodies], dtype=np.int8),
            radius=np.array([b.radius for b in self.bodies]),
            half_extents=np.stack([b.half_extents for b in self.bodies]),
            mass=mass,
            inv_mass=inv_mass,
            inertia_body=inertia,
            inv_inertia_body=inv_inertia,
            restitution=np.array([b.restitution for b in self.bodies]),
            friction=np.array([b.friction for b in self.bodies]),
            fixed=fixed,
            particles=[b.particles for b in self.bodies],
            color=np.stack([b.color for b in self.bodies]),
            predator=np.array([b.predator for b in self.bodies], dtype=bool),
            hulls=[b.hull for b in self.bodies],
            parts=[b.parts for b in self.bodies],
            meshes=[b.mesh for b in self.bodies],
            two_sided=np.array([b.two_sided for b in self.bodies], dtype=bool),
        )
        orientation = np.stack([b.orientation for b in self.bodies])
        from ..rotation import quat_to_matrix

        R = quat_to_matrix(orientation)
        # L₀ = I_world ω₀ with numpy's batched matmul, as every scene has been loaded since the first release: the
        # home of these equations (bodies.world_tensor, tensor_times: compiled loops) rounds differently (BLAS
        # fuses multiply-adds), and moving this line there changes the default scene's initial L in the last bit,
        # and every later tick with it (issue 24 kept trajectories bit-identical); move it with the next change
        # that may change trajectories
        inertia_world = R @ inertia @ np.swapaxes(R, -1, -2)
        lin_vel = np.stack([b.linear_velocity for b in self.bodies])
        ang_vel = np.stack([b.angular_velocity for b in self.bodies])
        movable = (~fixed)[:, None]
        state = BodyState(
            position=np.stack([b.position for b in self.bodies]),
            orientation=orientation,
            linear_momentum=mass[:, None] * lin_vel * movable,
            angular_momentum=np.einsum("nij,nj->ni", inertia_world, ang_vel) * movable,
        )
        return model, state


BODY_KEYS = {
    "name", "shape", "radius", "size", "length", "particles", "mass", "density", "position", "orientation",
    "linear_velocity", "angular_velocity", "restitution", "friction", "fixed", "color", "predator",
    "points", "mesh", "scale", "parts", "two_sided",
}
SHAPE_KEYS = {"sphere": {"radius"}, "box": {"size"}, "capsule": {"radius", "length"},
               "particles": {"particles", "radius"}, "convex": {"points", "mesh", "scale"}, "compound": {"parts"},
               "mesh": {"mesh", "scale", "two_sided"}}
#: the shapes a compound body's parts may have, and the keys of a part
PART_SHAPES = ("sphere", "box", "capsule", "convex")
PART_KEYS = {"shape", "radius", "size", "length", "points", "mesh", "scale", "position", "orientation"}

"""Rigid bodies as structure-of-arrays: a static :class:`BodyModel` apart from the dynamic :class:`BodyState`
(the MuJoCo split: what a scene defines never changes while stepping; what stepping changes is all in the
state, so reset is a copy and a step is a pure function of (model, state, dt)).

Conventions
-----------
- World frame ``world``: right-handed, z up, SI units (REP-103).
- Every body has a *body frame* whose origin is the body's centre of mass (COM).  For sphere, box and capsule
  the axes are the shape's own axes (box edges; capsule axis = body z).  For a particle set the axes are those
  of the scene's particle coordinates and the origin is moved to their COM (so ``position`` is always the COM,
  as the lecture's state vector has it), which makes the inertia tensor a full symmetric 3×3 matrix in general.
  A convex hull and a compound body likewise keep the axes of the points / parts as the scene gives them, with
  the origin moved to the COM.  A static mesh (fixed only: it has no COM that matters) keeps its file's origin
  and axes (times its ``scale``).
- Orientation is a unit quaternion ``(x, y, z, w)`` mapping body to world: ``p_world = x + R(q) p_body``.
- The state carries momenta, not velocities (the lecture's state: x, R, P, L); velocities are derived:
  ``v = P / m``, ``I_world = R I_body Rᵀ``, ``ω = I_world⁻¹ L``.
  Slide errata ("Whole Model" slides): the velocity is v = P/m (the slide writes v̇ = p/m, which would be an
  acceleration), and L = I ω is a matrix-vector product (the slide writes ``L = I × ω``); the inertia that
  maps ω to L is the world-frame R I_body Rᵀ, not the body-frame J the particles were summed in.
- Fixed bodies (walls, floors, obstacles) have ``inv_mass = 0`` and ``inv_inertia_body = 0``: every formula
  that divides by mass multiplies by the inverse instead, so they need no special case.

This module is the one home of the world-frame inertia equations, compiled so that the kernels call them too:
``I_world = R J Rᵀ`` (and ``I_world⁻¹ = R J⁻¹ Rᵀ``): :func:`world_tensor` / :func:`world_tensors`;
``ω = I_world⁻¹ L`` (and ``L = I_world ω``): :func:`tensor_times` / :func:`tensor_times_rows`.  The integrators
work in the body frame instead (Π = Rᵀ L: ``rotation.quat_rotate`` by the conjugate, Ω = J⁻¹ Π; see
:mod:`cgp_core.integrators.base`).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from .jit import njit
from .rotation import quat_to_matrix


class Shape(enum.IntEnum):
    """Collision / drawing shape of a body (values stored in ``BodyModel.shape``)."""

    SPHERE = 0
    BOX = 1
    CAPSULE = 2  # a segment of length ``2 * half_length`` along body z, swept by a sphere of ``radius``
    PARTICLES = 3  # the lecture's discrete body: point masses, each drawn and collided as a small sphere
    CONVEX = 4  # a convex polyhedron (BodyModel.hulls): the hull of the scene's points or of a mesh file
    COMPOUND = 5  # one rigid body made of parts (BodyModel.parts): spheres, boxes, capsules, hulls at relative poses
    MESH = 6  # a static triangle mesh with a BVH (BodyModel.meshes), for fixed bodies only (terrain, level geometry)


@dataclass
class CompoundParts:
    """The ``k`` parts of one compound body, in its body frame (origin = the body's COM, the scene's axes).

    Attributes (shapes):
        shape:        (k,) int8 — ``Shape.SPHERE``, ``BOX``, ``CAPSULE`` or ``CONVEX``.
        position:     (k, 3) — the part's centre in the body frame (a convex part's: its own COM).
        rotation:     (k, 3, 3) — the part's axes in body axes (columns).
        radius:       (k,) — sphere / capsule radius; 0 for boxes and hulls.
        half_extents: (k, 3) — box half sizes; capsule (0, 0, half_length); zeros for spheres and hulls.
        hulls:        list of k — a convex part's :class:`~cgp_core.collision.convex.ConvexPolyhedron` about its
                      COM in the part's axes; ``None`` for the other parts.
        mass:         (k,) — each part's share of the body's mass [kg].
    """

    shape: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    radius: np.ndarray
    half_extents: np.ndarray
    hulls: list
    mass: np.ndarray

    @property
    def count(self) -> int:
        return len(self.shape)


def rigid_work(parts: list, particles: list) -> tuple[int, int]:
    """``(shapes, particles)`` of bodies given by their parts (a :class:`CompoundParts` or None each) and their
    particles (a (k, 4) array or None each): a body is one shape, a compound body one per part; the particles of
    every particle body together.  See :data:`cgp_core.limits.MAX_SHAPE_SUBSTEPS`."""
    shapes = sum(1 if p is None else p.count for p in parts)
    return shapes, sum(len(k) for k in particles if k is not None)


@dataclass
class BodyModel:
    """Static description of ``n`` bodies.  Arrays are indexed by body in scene order.

    Attributes (shapes):
        names:            list[str], length n — unique, ROS-name-safe.
        shape:            (n,) int8 — :class:`Shape` values.
        radius:           (n,) — sphere / capsule radius; particle radius for PARTICLES; 0 for boxes and the
                          shapes of issue 25 (CONVEX, COMPOUND, MESH).
        half_extents:     (n, 3) — box half sizes along body x, y, z; capsule: (0, 0, half_length); bounding
                          half extents of the particle set for PARTICLES; for CONVEX, COMPOUND and MESH the
                          half extents of a box about the body origin that holds the whole shape.
        mass:             (n,) — kg (the configured mass, also for fixed bodies, for drawing / reporting).
        inv_mass:         (n,) — 1/kg, 0 for fixed bodies.
        inertia_body:     (n, 3, 3) — inertia tensor about the COM in body axes (kg m²).
        inv_inertia_body: (n, 3, 3) — its inverse, zeros for fixed bodies.
        restitution:      (n,) — coefficient of restitution e in [0, 1].
        friction:         (n,) — Coulomb friction coefficient μ >= 0.
        fixed:            (n,) bool — immovable (infinite mass); still collides.
        particles:        list of (k_i, 4) arrays [x, y, z, m] in body frame (COM origin) for PARTICLES
                          bodies, ``None`` for others.
        color:            (n, 4) — RGBA in [0, 1] for markers.
        predator:         (n,) bool — the boids of every flock flee it (``boids/predators.py``); all False when
                          not given.
        hulls:            list of n — a CONVEX body's :class:`~cgp_core.collision.convex.ConvexPolyhedron` in
                          the body frame (vertices about the COM), ``None`` for others; all ``None`` when not
                          given.
        parts:            list of n — a COMPOUND body's :class:`CompoundParts`, ``None`` for others.
        meshes:           list of n — a MESH body's :class:`~cgp_core.collision.bvh.StaticMesh` (vertices in the
                          body frame, its BVH built once at load), ``None`` for others.
        two_sided:        (n,) bool — a MESH body's triangles push from both sides (default: only from their
                          front, the side their counter-clockwise winding faces: a terrain's up).
    """

    names: list[str]
    shape: np.ndarray
    radius: np.ndarray
    half_extents: np.ndarray
    mass: np.ndarray
    inv_mass: np.ndarray
    inertia_body: np.ndarray
    inv_inertia_body: np.ndarray
    restitution: np.ndarray
    friction: np.ndarray
    fixed: np.ndarray
    particles: list
    color: np.ndarray
    predator: np.ndarray | None = None
    hulls: list | None = None
    parts: list | None = None
    meshes: list | None = None
    two_sided: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.names)
        if self.predator is None:
            self.predator = np.zeros(n, dtype=bool)
        for name in ("hulls", "parts", "meshes"):
            if getattr(self, name) is None:
                setattr(self, name, [None] * n)
        if self.two_sided is None:
            self.two_sided = np.zeros(n, dtype=bool)

    @property
    def has_convex_phase_shapes(self) -> bool:
        """Whether a body is a hull, a compound or a static mesh (the contacts of those run in
        :mod:`cgp_core.collision.convex_phase`)."""
        return bool(np.isin(self.shape, (Shape.CONVEX, Shape.COMPOUND, Shape.MESH)).any())

    @property
    def count(self) -> int:
        return len(self.names)

    def rigid_work(self) -> tuple[int, int]:
        """``(shapes, particles)`` of these bodies, the counts a tick's work is bounded by
        (:func:`cgp_core.limits.rigid_work_refusal`)."""
        return rigid_work(self.parts, self.particles)

    def index(self, name: str) -> int:
        """Index of the body called ``name``; ``KeyError`` naming the known bodies otherwise."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"unknown body {name!r}; bodies are: {', '.join(self.names) or '(none)'}") from None

    def bounding_radius(self) -> np.ndarray:
        """(n,) radius of a sphere about each body's COM that holds its whole shape [m] (``half_extents``
        bound the box, the capsule's segment and the particle centres; ``radius`` sweeps them)."""
        return np.linalg.norm(self.half_extents, axis=1) + self.radius

    @staticmethod
    def empty() -> BodyModel:
        return BodyModel(
            names=[],
            shape=np.zeros(0, dtype=np.int8),
            radius=np.zeros(0),
            half_extents=np.zeros((0, 3)),
            mass=np.zeros(0),
            inv_mass=np.zeros(0),
            inertia_body=np.zeros((0, 3, 3)),
            inv_inertia_body=np.zeros((0, 3, 3)),
            restitution=np.zeros(0),
            friction=np.zeros(0),
            fixed=np.zeros(0, dtype=bool),
            particles=[],
            color=np.zeros((0, 4)),
        )


@dataclass
class BodyState:
    """Dynamic state of ``n`` bodies (all float64, world frame).

    Attributes (shapes):
        position:         (n, 3) — COM x [m].
        orientation:      (n, 4) — unit quaternion (x, y, z, w), body → world.
        linear_momentum:  (n, 3) — P = m v [kg m/s].
        angular_momentum: (n, 3) — L = I_world ω about the COM [kg m²/s].
        force:            (n, 3) — force accumulator for the current step [N]; cleared after each step.
        torque:           (n, 3) — torque accumulator about the COM [N m]; cleared after each step.
        rotation:         (n, 3, 3) or None — only for integrators that integrate the matrix itself (the
                          lecture's explicit Euler); when set, it is authoritative and ``orientation`` is
                          its nearest rotation, kept in sync by that integrator.
    """

    position: np.ndarray
    orientation: np.ndarray
    linear_momentum: np.ndarray
    angular_momentum: np.ndarray
    force: np.ndarray = field(default=None)  # type: ignore[assignment]
    torque: np.ndarray = field(default=None)  # type: ignore[assignment]
    rotation: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.position)
        if self.force is None:
            self.force = np.zeros((n, 3))
        if self.torque is None:
            self.torque = np.zeros((n, 3))

    @property
    def count(self) -> int:
        return len(self.position)

    def copy(self) -> BodyState:
        return BodyState(
            position=self.position.copy(),
            orientation=self.orientation.copy(),
            linear_momentum=self.linear_momentum.copy(),
            angular_momentum=self.angular_momentum.copy(),
            force=self.force.copy(),
            torque=self.torque.copy(),
            rotation=None if self.rotation is None else self.rotation.copy(),
        )

    def clear_accumulators(self) -> None:
        self.force[:] = 0.0
        self.torque[:] = 0.0

    # ---- derived quantities (never stored, so they cannot go stale) ----

    def rotation_matrices(self) -> np.ndarray:
        """R (n, 3, 3): the integrator's own matrix when it keeps one, else from the quaternion."""
        return self.rotation if self.rotation is not None else quat_to_matrix(self.orientation)

    def linear_velocity(self, model: BodyModel) -> np.ndarray:
        """v = P / m, (n, 3); zero for fixed bodies."""
        return self.linear_momentum * model.inv_mass[:, None]

    def inv_inertia_world(self, model: BodyModel, R: np.ndarray | None = None) -> np.ndarray:
        """I_world⁻¹ = R I_body⁻¹ Rᵀ, (n, 3, 3) (:func:`world_tensors`)."""
        R = self.rotation_matrices() if R is None else R
        return world_tensors(np.ascontiguousarray(R, dtype=float), np.ascontiguousarray(model.inv_inertia_body))

    def angular_velocity(self, model: BodyModel, R: np.ndarray | None = None) -> np.ndarray:
        """ω = I_world⁻¹ L, (n, 3), world frame (:func:`tensor_times_rows`)."""
        return tensor_times_rows(self.inv_inertia_world(model, R), np.ascontiguousarray(self.angular_momentum))

    def kinetic_energy(self, model: BodyModel) -> np.ndarray:
        """Per-body kinetic energy ½ P·v + ½ L·ω, (n,)."""
        v = self.linear_velocity(model)
        w = self.angular_velocity(model)
        return 0.5 * np.einsum("ni,ni->n", self.linear_momentum, v) + 0.5 * np.einsum(
            "ni,ni->n", self.angular_momentum, w
        )


# ---- the world-frame inertia: one home, compiled ------------------------------------------------------------

@njit
def world_tensor(R, T, out):
    """``out = R T Rᵀ`` (3, 3): a body-frame tensor ``T`` (3, 3) — the inertia J, or J⁻¹ — in world axes, for a
    body turned by ``R`` (3, 3): I_world = R J Rᵀ, I_world⁻¹ = R J⁻¹ Rᵀ."""
    for r in range(3):
        rt0 = R[r, 0] * T[0, 0] + R[r, 1] * T[1, 0] + R[r, 2] * T[2, 0]  # row r of R T
        rt1 = R[r, 0] * T[0, 1] + R[r, 1] * T[1, 1] + R[r, 2] * T[2, 1]
        rt2 = R[r, 0] * T[0, 2] + R[r, 1] * T[1, 2] + R[r, 2] * T[2, 2]
        for c in range(3):
            out[r, c] = rt0 * R[c, 0] + rt1 * R[c, 1] + rt2 * R[c, 2]


@njit
def world_tensors(R, T):
    """:func:`world_tensor` of n bodies: ``R``, ``T`` (n, 3, 3) → (n, 3, 3)."""
    out = np.empty((len(R), 3, 3))
    for i in range(len(R)):
        world_tensor(R[i], T[i], out[i])
    return out


@njit
def tensor_times(T, x, y, z):
    """``T v`` for a (3, 3) tensor and v = (x, y, z): ω = I_world⁻¹ L, L = I_world ω.  Returns the three
    components."""
    out0 = 0.0
    out1 = 0.0
    out2 = 0.0
    out0 += T[0, 0] * x
    out0 += T[0, 1] * y
    out0 += T[0, 2] * z
    out1 += T[1, 0] * x
    out1 += T[1, 1] * y
    out1 += T[1, 2] * z
    out2 += T[2, 0] * x
    out2 += T[2, 1] * y
    out2 += T[2, 2] * z
    return out0, out1, out2


@njit
def tensor_times_rows(T, v):
    """:func:`tensor_times` of n bodies: ``T`` (n, 3, 3), ``v`` (n, 3) → (n, 3)."""
    out = np.empty((len(T), 3))
    for i in range(len(T)):
        out[i, 0], out[i, 1], out[i, 2] = tensor_times(T[i], v[i, 0], v[i, 1], v[i, 2])
    return out

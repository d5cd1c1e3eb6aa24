"""A robot as a static model: the kinematic tree of rigid bodies and joints read from a URDF, as arrays.

MuJoCo's split: :class:`RobotModel` holds what does not change while a robot moves (the tree, the joint frames and
axes, masses, inertias, limits, geometry); the dynamic state is the vectors ``q`` (positions, ``n_q``) and ``qd``
(velocities, ``n_dofs``) the algorithms of :mod:`cgp_core.robots.algorithms` take.  Bodies are numbered parent
before child (``parent[i] < i``), the order every recursive algorithm loops in.

Bodies and frames.  A *body* is what the dynamics moves: a URDF link reached through a moving joint (or the root),
with every link hanging from it through fixed joints merged in (masses, COMs and inertias summed by the
parallel-axis theorem).  Every URDF link stays a *frame* (``frame_names``), rigidly attached to a body at a constant
pose, because TF publishes them all.

Frames of a body and its joint.  URDF puts the child link's frame on the joint frame: body ``i``'s frame is its
joint frame (``joint_rotation[i]``, ``joint_position[i]`` in the parent body's frame, the world's for the root)
moved by the joint:

- ``JOINT_REVOLUTE``: turned by ``q`` [rad] about ``joint_axis`` (right hand);
- ``JOINT_PRISMATIC``: translated by ``q`` [m] along ``joint_axis``;
- ``JOINT_PLANAR``: translated by ``q[0] u + q[1] v`` [m] then turned by ``q[2]`` [rad] about ``joint_axis``,
  where ``(u, v) = plane_basis(joint_axis)`` (for the axis z: u = x, v = y); velocities are the time derivatives
  of these three numbers;
- ``JOINT_FLOATING`` (root only; its joint frame is the world's: identity rotation, zero position): ``q = (x, y,
  z, qx, qy, qz, qw)``, the body frame's origin in the world [m] and its orientation as a unit quaternion in ROS
  order.  **Velocity convention**: ``qd = (v, ω)``, the velocity of the root body frame's origin and the angular
  velocity, both **in world coordinates** [m/s, rad/s] (Pinocchio's free flyer uses the body frame's
  coordinates for both: ``v_world = R v_local``, ``ω_world = R ω_local``); generalized forces ``tau`` are their
  conjugates: the world force [N] at the root origin and the world torque [N m] about it;
- ``JOINT_BALL`` (a spherical joint; scene ``joints:`` of type ``ball``, URDF has none): ``q = (qx, qy, qz,
  qw)``, the body frame's orientation in its joint frame as a unit quaternion (ROS order; the body frame's origin
  stays at the joint frame's, the ball's centre).  **Velocity convention**: ``qd = ω`` (3), the angular velocity
  of the body relative to its parent in the **joint frame's axes** (a frame fixed in the parent), so a ball is
  three revolute columns about parent-fixed axes through its centre; Pinocchio's ``JointModelSpherical`` uses the
  child frame's axes instead: ``ω_joint = R(q) ω_local``.  Integrated like the floating root's orientation,
  ``q ← exp(h ω) ⊗ q`` (ω in the joint frame multiplies on the left), normalized;
- ``JOINT_FIXED_ROOT``: the root welded to the world at its joint frame, no coordinates.

Mimic joints (``<mimic>``) are kept as data: ``q[f] = multiplier q[l] + offset`` for the dof pairs listed; the
dynamics here treat a follower as a joint of its own (as Pinocchio does without its mimic flag) and a solver
adds the coupling as a constraint.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

__all__ = ["JOINT_FIXED_ROOT", "JOINT_FLOATING", "JOINT_REVOLUTE", "JOINT_PRISMATIC", "JOINT_PLANAR",
           "JOINT_BALL", "JOINT_DOFS", "Geometry", "RobotModel", "RobotArrays", "robot_arrays", "neutral_positions",
           "plane_basis"]

JOINT_FIXED_ROOT = 0   # the root body welded to the world (fixed base): 0 dof
JOINT_FLOATING = 1     # 6 dof (root only)
JOINT_REVOLUTE = 2     # 1 dof about joint_axis (URDF revolute and continuous)
JOINT_PRISMATIC = 3    # 1 dof along joint_axis
JOINT_PLANAR = 4       # 3 dof: translation in the plane normal to joint_axis + rotation about it
JOINT_BALL = 5         # 3 dof: rotation about the joint frame's origin (q: a unit quaternion, 4 coordinates)

#: (dofs, position coordinates) of each joint type, indexed by the constants above
JOINT_DOFS = ((0, 0), (6, 7), (1, 1), (1, 1), (3, 3), (3, 4))


@dataclass(frozen=True, eq=False)
class Geometry:
    """One collision or visual shape of a body, in the body's frame.

    kind: ``'box'`` | ``'sphere'`` | ``'cylinder'`` | ``'mesh'``.
    size: box: full extents (3,) [m]; sphere: (radius,) [m]; cylinder: (radius, length) [m], axis = z of its frame;
        mesh: (0,).
    rotation (3, 3), position (3,) [m]: the shape's frame in the body's frame.
    mesh_path: the mesh file, resolved to an absolute path (mesh only; None otherwise).
    mesh_scale: (3,) scale factors of the mesh's coordinates (ones for the other kinds).
    rgba: (4,) colour in [0, 1] (visuals with a material colour), or None.
    link: the URDF link the shape was declared in (a merged link's shapes sit on its parent's body).
    """

    kind: str
    size: np.ndarray
    rotation: np.ndarray
    position: np.ndarray
    mesh_path: str | None
    mesh_scale: np.ndarray
    rgba: np.ndarray | None
    link: str

    def __deepcopy__(self, memo):
        # immutable (frozen, its arrays never written): a deep copy of a world (the node's warm-up) shares it, so
        # that what is keyed by its identity (its drawing, cgp_sim_ros/drawing/robots.py) is not made again
        return self


@dataclass(frozen=True, eq=False, repr=False)
class RobotModel:
    """The static model of one robot (see the module docstring for the frame and velocity conventions).

    Per body (n, parent before child):
        body_names: the URDF link heading each body.
        parent: (n,) int64, the parent body, -1 for the root (whose parent is the world).
        joint_names: the URDF joint from the parent to the body ('' for the root: no URDF joint leads to it).
        joint_type: (n,) int64, one of the JOINT_* constants.
        joint_rotation (n, 3, 3), joint_position (n, 3) [m]: the joint frame in the parent body's frame (the
            world's for the root), at q = 0.
        joint_axis: (n, 3) unit axis in the joint frame (zeros for fixed, floating and ball).
        dof_start, dof_count: (n,) int64 — the body's velocities are ``qd[dof_start : dof_start + dof_count]``.
        q_start, q_count: (n,) int64 — its positions (floating root: 7, position + quaternion xyzw; ball: 4, the
            quaternion xyzw).
        mass: (n,) [kg], merged.
        com: (n, 3) [m], the centre of mass in the body frame.
        inertia: (n, 3, 3) [kg m²], about the COM, in the body frame's axes (URDF inertial rpy applied: R I Rᵀ).
    Per dof:
        dof_names: (n_dofs,) the joint's name (planar: suffixed ``/x``, ``/y``, ``/theta``; floating: ``/x``,
            ``/y``, ``/z``, ``/wx``, ``/wy``, ``/wz``; ball: ``/wx``, ``/wy``, ``/wz``).
        lower, upper: (n_dofs,) position limits [rad or m]; -inf / +inf for continuous, planar, floating, ball.
        effort_limit, velocity_limit: (n_dofs,) [N m or N], [rad/s or m/s]; +inf where the URDF gives none, and
            where it gives 0 (URDF files write 0 for "not given"; a joint that may exert no effort is not meant).
        damping: (n_dofs,) URDF ``<dynamics damping>``, viscous [N m s/rad or N s/m].
        friction: (n_dofs,) URDF ``<dynamics friction>``, Coulomb [N m or N].
    Mimic (k pairs): mimic_follower, mimic_leader (k,) int64 dof indices; q_f = multiplier q_l + offset:
        mimic_multiplier, mimic_offset (k,).
    Frames (f, every URDF link): frame_names; frame_body (f,) int64 the body each is attached to; frame_rotation
        (f, 3, 3), frame_position (f, 3) [m] the frame in that body's frame.
    collisions, visuals: per body, its :class:`Geometry` in the body frame (merged links' shapes moved there).
    source: the URDF XML as loaded (xacro expanded), for ``robot_description``.
    """

    name: str
    body_names: tuple[str, ...]
    parent: np.ndarray
    joint_names: tuple[str, ...]
    joint_type: np.ndarray
    joint_rotation: np.ndarray
    joint_position: np.ndarray
    joint_axis: np.ndarray
    dof_start: np.ndarray
    dof_count: np.ndarray
    q_start: np.ndarray
    q_count: np.ndarray
    n_dofs: int
    n_q: int
    mass: np.ndarray
    com: np.ndarray
    inertia: np.ndarray
    dof_names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    effort_limit: np.ndarray
    velocity_limit: np.ndarray
    damping: np.ndarray
    friction: np.ndarray
    mimic_follower: np.ndarray
    mimic_leader: np.ndarray
    mimic_multiplier: np.ndarray
    mimic_offset: np.ndarray
    frame_names: tuple[str, ...]
    frame_body: np.ndarray
    frame_rotation: np.ndarray
    frame_position: np.ndarray
    collisions: tuple[tuple[Geometry, ...], ...]
    visuals: tuple[tuple[Geometry, ...], ...]
    source: str

    def __repr__(self) -> str:
        return (f"RobotModel({self.name!r}: {self.n_bodies} bodies, {self.n_dofs} dofs, "
                f"{len(self.frame_names)} frames)")

    @property
    def n_bodies(self) -> int:
        return len(self.body_names)

    @property
    def arrays(self) -> RobotArrays:
        """The bundle the compiled algorithms take (built once per model)."""
        cached = self.__dict__.get("_arrays")
        if cached is None:
            cached = robot_arrays(self)
            object.__setattr__(self, "_arrays", cached)
        return cached

    def body_index(self, name: str) -> int:
        """The body whose frame is the URDF link ``name`` (a merged link: the body it is merged into)."""
        return int(self.frame_body[self.frame_names.index(name)])

    def dof_index(self, joint: str) -> int:
        """The first dof of the joint named ``joint``."""
        return int(self.dof_start[self.joint_names.index(joint)])


class RobotArrays(NamedTuple):
    """The arrays of a :class:`RobotModel` the compiled algorithms read (shapes and units as there; n bodies,
    f frames)."""

    parent: np.ndarray          # (n,) int64, -1 for the root
    joint_type: np.ndarray      # (n,) int64
    joint_rotation: np.ndarray  # (n, 3, 3)
    joint_position: np.ndarray  # (n, 3) [m]
    joint_axis: np.ndarray      # (n, 3) unit, joint frame
    plane_u: np.ndarray         # (n, 3) planar joints: first in-plane direction (joint frame); zeros otherwise
    plane_v: np.ndarray         # (n, 3) planar joints: second in-plane direction, axis × u
    dof_start: np.ndarray       # (n,) int64
    dof_count: np.ndarray       # (n,) int64
    q_start: np.ndarray         # (n,) int64
    q_count: np.ndarray         # (n,) int64
    mass: np.ndarray            # (n,) [kg]
    com: np.ndarray             # (n, 3) [m] body frame
    inertia: np.ndarray         # (n, 3, 3) [kg m²] about the COM, body axes
    frame_body: np.ndarray      # (f,) int64
    frame_rotation: np.ndarray  # (f, 3, 3)
    frame_position: np.ndarray  # (f, 3) [m]
    dof_body: np.ndarray        # (n_dofs,) int64, the body each dof moves
    n_dofs: int
    n_q: int


class RobotStarts(NamedTuple):
    """Where robot ``k``'s part is in arrays holding every robot's side by side (concatenated along axis 0, CSR
    style): rows ``start[k]`` … ``start[k + 1]``.  Each (robots + 1,) int64, the last entry the total."""

    body: np.ndarray            # bodies (one joint each): the per-body fields of RobotArrays
    frame: np.ndarray           # frames (every URDF link): frame_body, frame_rotation, frame_position
    dof: np.ndarray             # velocities: qd, dof_body, the joint solver's per-dof properties and drives
    q: np.ndarray               # positions
    mimic: np.ndarray           # mimic couplings
    equality: np.ndarray        # the joint solver's equality rows (loop closures)
    equality_entry: np.ndarray  # entries of the flattened (e, n_dofs) equality Jacobians


def row_starts(sizes) -> np.ndarray:
    """The :class:`RobotStarts` entry of parts of ``sizes`` rows each, side by side: ``(len(sizes) + 1,)`` int64,
    0 first and the total last."""
    return np.concatenate(([0], np.cumsum(sizes))).astype(np.int64)


def stack_robot_arrays(bundles: list) -> RobotArrays:
    """Every robot's :class:`RobotArrays` in one bundle: each array field concatenated along axis 0 (robot ``k``'s
    rows at its :class:`RobotStarts`; :func:`cgp_core.robots.algorithms.robot_view` takes them out again), the index
    fields (parent, dof_start, q_start, frame_body, dof_body) left each robot's own; n_dofs and n_q the totals.
    ``bundles``: one RobotArrays (or plain tuple) per robot, at least one."""
    arrays = len(RobotArrays._fields) - 2  # all but n_dofs, n_q
    fields = [np.ascontiguousarray(np.concatenate([b[i] for b in bundles])) for i in range(arrays)]
    return RobotArrays(*fields, int(sum(b[-2] for b in bundles)), int(sum(b[-1] for b in bundles)))


def plane_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The in-plane directions ``(u, v)`` of a planar joint with unit normal ``axis`` (3,): ``u`` is the coordinate
    axis least aligned with ``axis`` (the first of equals) made orthogonal to it, ``v = axis × u``; for axis z:
    (x, y)."""
    axis = np.asarray(axis, dtype=float)
    e = np.zeros(3)
    e[int(np.argmin(np.abs(axis)))] = 1.0
    u = e - (e @ axis) * axis
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def robot_arrays(model: RobotModel) -> RobotArrays:
    """The :class:`RobotArrays` bundle of ``model`` (contiguous float64 / int64 copies)."""
    n = model.n_bodies
    plane_u = np.zeros((n, 3))
    plane_v = np.zeros((n, 3))
    for i in range(n):
        if model.joint_type[i] == JOINT_PLANAR:
            plane_u[i], plane_v[i] = plane_basis(model.joint_axis[i])
    dof_body = np.repeat(np.arange(n, dtype=np.int64), model.dof_count)

    def f(a):
        return np.ascontiguousarray(a, dtype=np.float64)

    def i64(a):
        return np.ascontiguousarray(a, dtype=np.int64)

    return RobotArrays(i64(model.parent), i64(model.joint_type), f(model.joint_rotation), f(model.joint_position),
                       f(model.joint_axis), plane_u, plane_v, i64(model.dof_start), i64(model.dof_count),
                       i64(model.q_start), i64(model.q_count), f(model.mass), f(model.com), f(model.inertia),
                       i64(model.frame_body), f(model.frame_rotation), f(model.frame_position), i64(dof_body),
                       int(model.n_dofs), int(model.n_q))


def neutral_positions(model: RobotModel) -> np.ndarray:
    """``q`` (n_q,) at the neutral configuration: zeros, with the identity quaternion (0, 0, 0, 1) for a floating
    root and a ball joint."""
    q = np.zeros(model.n_q)
    for i in range(model.n_bodies):
        if model.joint_type[i] == JOINT_FLOATING:
            q[model.q_start[i] + 6] = 1.0
        elif model.joint_type[i] == JOINT_BALL:
            q[model.q_start[i] + 3] = 1.0
    return q

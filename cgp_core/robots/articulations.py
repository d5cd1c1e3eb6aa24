"""Joints between a scene's free bodies (``joints:``, issue 35) as articulations in reduced coordinates.

The joints of a scene that form a tree over its bodies become a :class:`~cgp_core.robots.model.RobotModel`,
stepped by :class:`~cgp_core.robots.world.Robots` exactly like a URDF robot (joint-space solve, the bodies'
contacts as rows): a joint cannot stretch, whatever the mass ratios.  The bodies stay the scene's own bodies
(same names, markers, contacts, TF): they are the robot's links, their motion computed from the joint space.

How the trees are built (:func:`build_articulations`):

- a joint's ``parent`` is ``world``, a fixed body (both: the static world), or a free body; its ``child`` a free
  body.  The first joint naming a body as its child is the body's **tree joint**; following tree joints up from a
  body ends at the world (a *grounded* tree) or at a body that is no joint's child (a *floating* tree's root);
- every grounded tree of the scene that a loop joins to another becomes one model with a massless fixed root at
  the world origin (``<name>/world``, no world body); a floating tree is one model whose root body has a FLOATING
  joint (6 dof: the body's COM position and orientation);
- a model body's frame is the scene body's axes at the scene's initial pose with its origin at the anchor of its
  tree joint (the root of a floating tree: at its COM): a revolute joint turns the body about the axis through
  the anchor, a prismatic one moves it along the axis, a ``ball`` one turns it about the anchor (a spherical joint:
  3 dofs, the angular velocity in the joint frame's axes, which are the child's axes at the scene's initial pose
  carried by the parent; its position a quaternion, see :mod:`~cgp_core.robots.model`), a ``fixed`` one welds it
  (a 0-dof joint).  Every joint's coordinate is 0 (a ball's quaternion the identity) at the scene's initial poses;
  ``limits`` are relative to them.  Mass, COM and inertia are the
  body's (:class:`~cgp_core.scene.specs.BodySpec`);
- a joint whose child already has a tree joint **closes a loop** (a four-bar's fourth pin): it must join bodies
  of one model (or the world and a grounded tree) and is three equality rows of the joint solver, the anchor
  points of its two bodies made to coincide: J = J_point(a) − J_point(b), C = p_a − p_b, re-linearised every
  sub-step (:meth:`LoopClosure.rows`).  Only the point is constrained: exactly a ball joint's constraint, and a
  revolute loop joint's when its axis is parallel to the others' (a planar mechanism needs no more; the two
  rotational rows a revolute loop joint would add out of the plane are not there); its limits and drives are
  refused.
- the initial joint velocities are the least-squares fit of the bodies' scene velocities (exact when they are
  consistent with the joints, e.g. all zero).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..rotation import quat_to_matrix
from . import algorithms
from .model import (
    JOINT_BALL,
    JOINT_DOFS,
    JOINT_FIXED_ROOT,
    JOINT_FLOATING,
    JOINT_PRISMATIC,
    JOINT_REVOLUTE,
    RobotModel,
    neutral_positions,
)

#: the scene's joint types and the model's joint type each becomes
JOINT_TYPES = {"revolute": JOINT_REVOLUTE, "prismatic": JOINT_PRISMATIC, "fixed": JOINT_FIXED_ROOT,
               "ball": JOINT_BALL}
#: a loop-closure row whose Jacobian is this small next to its triple's largest is zeroed (a planar
#: mechanism's out-of-plane row is round-off: solving it would divide by ~1e-34)
DEGENERATE_ROW = 1e-9
WORLD = "world"


@dataclass
class LoopClosure:
    """A loop-closing joint of one model: the anchor on body ``a`` (model body index, −1: the world) must
    coincide with the anchor on body ``b``; ``point_a`` / ``point_b`` in their body's frame (the world's for −1)."""

    name: str
    a: int
    point_a: np.ndarray
    b: int
    point_b: np.ndarray

    def points(self, rotation: np.ndarray, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The two anchor points in the world at the body poses of forward kinematics."""
        pa = self.point_a if self.a < 0 else position[self.a] + rotation[self.a] @ self.point_a
        pb = self.point_b if self.b < 0 else position[self.b] + rotation[self.b] @ self.point_b
        return pa, pb

    def rows(self, arrays, rotation, position) -> tuple[np.ndarray, np.ndarray]:
        """``(J (3, n_dofs), C (3,))``: the world x, y, z rows of p_a − p_b; a row that is round-off next to the
        largest is zeroed (inert)."""
        pa, pb = self.points(rotation, position)
        J = np.zeros((3, arrays.n_dofs))
        kernel = tuple(arrays)  # (the plain tuple the world's every call passes: one compile of the kernel)
        if self.a >= 0:
            J += algorithms.point_jacobian(kernel, rotation, position, self.a, pa)
        if self.b >= 0:
            J -= algorithms.point_jacobian(kernel, rotation, position, self.b, pb)
        C = pa - pb
        norms = np.linalg.norm(J, axis=1)
        small = norms <= DEGENERATE_ROW * max(float(norms.max()), 1e-300)
        J[small] = 0.0
        C[small] = 0.0
        return J, C


@dataclass
class Articulation:
    """What :func:`build_articulations` makes of one tree: the model, where it starts, its loop closures."""

    name: str
    model: RobotModel
    position: np.ndarray      # the floating root's COM (zeros for a grounded tree)
    orientation: np.ndarray   # the floating root's orientation xyzw (identity for a grounded tree)
    velocity: np.ndarray      # (n_dofs,) initial joint velocities
    loops: list[LoopClosure] = field(default_factory=list)
    drives: dict = field(default_factory=dict)  # joint name -> the scene's drive mapping
    fixed_parents: list[str] = field(default_factory=list)  # fixed bodies its joints hang from (no contacts
    #                                                           with the bodies jointed to them)

    @property
    def loop_pairs(self) -> set[tuple[int, int]]:
        """The (smaller, larger) model body indices each loop-closing joint joins (they do not collide)."""
        return {(min(loop.a, loop.b), max(loop.a, loop.b)) for loop in self.loops}


class ArticulationError(ValueError):
    """A set of joints that cannot be built; ``key`` is the scene key path it is about."""

    def __init__(self, key: str, reason: str):
        super().__init__(f"{key}: {reason}")
        self.key, self.reason = key, reason


def _pose(body):
    R = quat_to_matrix(np.asarray(body.orientation, float)[None])[0]
    return R, np.asarray(body.position, float)


def build_articulations(bodies: list, joints: list) -> list[Articulation]:
    """The articulations of the scene's ``joints`` (:class:`~cgp_core.scene.joints.JointSpec`, validated one by
    one) over its ``bodies`` (:class:`~cgp_core.scene.specs.BodySpec`); :class:`ArticulationError` naming the
    joint for a set that is no tree plus loops (see the module docstring)."""
    by_name = {b.name: b for b in bodies}

    def grounded_parent(name: str) -> bool:
        return name == WORLD or bool(by_name[name].fixed)

    tree_joint: dict[str, int] = {}  # child body -> its tree joint's index
    loops: list[int] = []
    for k, j in enumerate(joints):
        if j.child in tree_joint:
            loops.append(k)
        else:
            tree_joint[j.child] = k

    def top(name: str, k: int) -> str:
        """The body at the top of ``name``'s tree: world-jointed (grounded) or a floating root."""
        seen = set()
        while name in tree_joint and not grounded_parent(joints[tree_joint[name]].parent):
            if name in seen:
                raise ArticulationError(f"joints[{k}]", f"the joints through {name} form a cycle with no root "
                                                          f"(nothing jointed to the world or left free)")
            seen.add(name)
            name = joints[tree_joint[name]].parent
        return name

    def is_grounded(top_body: str) -> bool:
        return top_body in tree_joint and grounded_parent(joints[tree_joint[top_body]].parent)

    tops = {name: top(name, tree_joint[name]) for name in tree_joint}
    for j in joints:  # floating roots (a parent that is no joint's child)
        if not grounded_parent(j.parent) and j.parent not in tops:
            tops[j.parent] = j.parent
    # group the trees: one per top, grounded ones joined by the loops between them
    group = {t: t for t in set(tops.values())}

    def find(t):
        while group[t] != t:
            t = group[t]
        return t

    for k in loops:
        j = joints[k]
        ta = None if grounded_parent(j.parent) else tops[j.parent]
        tb = tops[j.child]
        if ta is None:
            if not is_grounded(tb):
                raise ArticulationError(f"joints[{k}].child", f"{j.child} already hangs from joint "
                                        f"{joints[tree_joint[j.child]].name} in a free-floating tree: a second joint "
                                        f"to the world may close a loop only in a tree jointed to the world")
            continue
        if find(ta) == find(tb):
            continue
        if is_grounded(ta) and is_grounded(tb):
            group[find(ta)] = find(tb)
            continue
        raise ArticulationError(f"joints[{k}].child", f"{j.child} is already the child of joint "
                                f"{joints[tree_joint[j.child]].name}; a second joint may only close a loop within one "
                                f"tree, and {j.parent} is in another (free-floating) tree")
    members: dict[str, list[str]] = {}
    order = [j.child for j in joints if j.child in tree_joint] + [j.parent for j in joints]
    for name in dict.fromkeys(order):  # file order, each once
        if name in tops:
            members.setdefault(find(tops[name]), []).append(name)
    out = []
    for root_top, names in members.items():
        out.append(_build_one(root_top, names, joints, tree_joint, loops, by_name, grounded_parent, tops, find))
    return out


def _build_one(root_top, names, joints, tree_joint, loops, by_name, grounded_parent, tops, find) -> Articulation:
    grounded = root_top in tree_joint and grounded_parent(joints[tree_joint[root_top]].parent)
    first_joint = min(tree_joint[n] for n in names if n in tree_joint)
    name = joints[first_joint].name
    # bodies parent before child: breadth-first from the top(s), children in file order
    children: dict[str, list[str]] = {}
    for child, k in sorted(tree_joint.items(), key=lambda item: item[1]):
        if child in names:
            parent = WORLD if grounded_parent(joints[k].parent) else joints[k].parent
            children.setdefault(parent, []).append(child)
    start = [WORLD] if grounded else [root_top]
    ordered = []
    queue = list(start)
    while queue:
        b = queue.pop(0)
        ordered.append(b)
        queue += children.get(b, [])
    index = {b: i for i, b in enumerate(ordered)}
    n = len(ordered)
    parent = np.full(n, -1, np.int64)
    joint_type = np.zeros(n, np.int64)
    joint_rotation = np.tile(np.eye(3), (n, 1, 1))
    joint_position = np.zeros((n, 3))
    joint_axis = np.zeros((n, 3))
    mass, com, inertia = np.zeros(n), np.zeros((n, 3)), np.zeros((n, 3, 3))
    frame_R = np.tile(np.eye(3), (n, 1, 1))  # each body frame in the world at the initial poses
    frame_o = np.zeros((n, 3))
    joint_names = [""] * n
    body_names = [f"{name}/world" if b == WORLD else b for b in ordered]
    lower, upper, effort, damping, friction, dof_names = [], [], [], [], [], []
    drives = {}
    position0, orientation0 = np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])
    for i, b in enumerate(ordered):
        if b == WORLD:
            joint_type[i] = JOINT_FIXED_ROOT
            continue
        spec = by_name[b]
        R, x = _pose(spec)
        mass[i], inertia[i] = float(spec.mass), np.asarray(spec.inertia_body, float)
        frame_R[i] = R
        if b not in tree_joint:  # a floating root: frame at its COM
            joint_type[i] = JOINT_FLOATING
            frame_o[i] = x
            position0, orientation0 = x.copy(), np.asarray(spec.orientation, float).copy()
            dof_names += [f"{b}/{c}" for c in ("x", "y", "z", "wx", "wy", "wz")]
            lower += [-np.inf] * 6
            upper += [np.inf] * 6
            effort += [np.inf] * 6
            damping += [0.0] * 6
            friction += [0.0] * 6
            continue
        j = joints[tree_joint[b]]
        p = index[WORLD if grounded_parent(j.parent) else j.parent]
        parent[i] = p
        joint_names[i] = j.name
        joint_type[i] = JOINT_TYPES[j.type]
        frame_o[i] = j.anchor
        com[i] = R.T @ (x - j.anchor)
        joint_rotation[i] = frame_R[p].T @ R
        joint_position[i] = frame_R[p].T @ (j.anchor - frame_o[p])
        if joint_type[i] == JOINT_BALL:  # 3 dofs, no limits, drive or friction (refused by the scene's parser)
            dof_names += [f"{j.name}/{c}" for c in ("wx", "wy", "wz")]
            lower += [-np.inf] * 3
            upper += [np.inf] * 3
            effort += [np.inf] * 3
            damping += [j.damping] * 3  # viscous: τ = −c ω, the same for every axis
            friction += [0.0] * 3
        elif joint_type[i] != JOINT_FIXED_ROOT:
            joint_axis[i] = R.T @ j.axis
            dof_names.append(j.name)
            lo, hi = j.limits if j.limits is not None else (-np.inf, np.inf)
            lower.append(lo)
            upper.append(hi)
            effort.append(j.drive.get("effort_limit", np.inf) if j.drive else np.inf)
            damping.append(j.damping)
            friction.append(j.friction)
            if j.drive:
                drives[j.name] = dict(j.drive)
    dof_count = np.array([JOINT_DOFS[int(t)][0] for t in joint_type], np.int64)
    q_count = np.array([JOINT_DOFS[int(t)][1] for t in joint_type], np.int64)
    dof_start = np.concatenate([[0], np.cumsum(dof_count)[:-1]]).astype(np.int64)
    q_start = np.concatenate([[0], np.cumsum(q_count)[:-1]]).astype(np.int64)
    if not grounded:  # the floating root's joint frame is the world's
        joint_rotation[0], joint_position[0] = np.eye(3), np.zeros(3)
    model = RobotModel(
        name=name, body_names=tuple(body_names), parent=parent, joint_names=tuple(joint_names),
        joint_type=joint_type, joint_rotation=joint_rotation, joint_position=joint_position, joint_axis=joint_axis,
        dof_start=dof_start, dof_count=dof_count, q_start=q_start, q_count=q_count, n_dofs=int(dof_count.sum()),
        n_q=int(q_count.sum()), mass=mass, com=com, inertia=inertia, dof_names=tuple(dof_names),
        lower=np.array(lower, float), upper=np.array(upper, float), effort_limit=np.array(effort, float),
        velocity_limit=np.full(len(dof_names), np.inf), damping=np.array(damping, float),
        friction=np.array(friction, float), mimic_follower=np.zeros(0, np.int64),
        mimic_leader=np.zeros(0, np.int64), mimic_multiplier=np.zeros(0), mimic_offset=np.zeros(0),
        frame_names=tuple(body_names), frame_body=np.arange(n, dtype=np.int64),
        frame_rotation=np.tile(np.eye(3), (n, 1, 1)), frame_position=np.zeros((n, 3)),
        collisions=tuple(() for _ in range(n)), visuals=tuple(() for _ in range(n)), source="")
    loop_closures = []
    for k in loops:
        j = joints[k]
        if find(tops[j.child]) != root_top:
            continue
        ends = []
        for end in (j.parent, j.child):
            if grounded_parent(end):
                ends += [-1, np.asarray(j.anchor, float).copy()]
            else:
                i = index[end]
                ends += [i, frame_R[i].T @ (j.anchor - frame_o[i])]
        loop_closures.append(LoopClosure(j.name, *ends))
    fixed_parents = sorted({j.parent for j in joints if j.parent != WORLD and grounded_parent(j.parent)
                            and j.child in names})
    # the initial joint velocities: the least-squares fit of the bodies' scene velocities
    q = neutral_positions(model)
    if not grounded:
        q[0:3], q[3:7] = position0, orientation0
    arrays = tuple(model.arrays)  # (the plain tuple the world's kernels are called with: compiled once)
    rotation, position = algorithms.forward_kinematics(arrays, q)
    rows, targets = [], []
    for i, b in enumerate(ordered):
        if b == WORLD:
            continue
        spec = by_name[b]
        rows += [algorithms.point_jacobian(arrays, rotation, position, i, np.asarray(spec.position, float)),
                 algorithms.angular_jacobian(arrays, rotation, position, i)]
        targets += [np.asarray(spec.linear_velocity, float), np.asarray(spec.angular_velocity, float)]
    velocity = np.zeros(model.n_dofs)
    if model.n_dofs and rows:
        A, y = np.vstack(rows), np.concatenate(targets)
        if np.any(y != 0.0):
            velocity = np.linalg.lstsq(A, y, rcond=None)[0]
    return Articulation(name, model, position0, orientation0, velocity, loop_closures, drives, fixed_parents)

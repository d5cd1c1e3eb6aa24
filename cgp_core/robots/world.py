"""Robots in a :class:`~cgp_core.world.World`: the robot stage of each rigid-body sub-step.

Each robot is a system in **reduced coordinates**: its joint positions ``q`` and velocities ``qd`` (all robots'
side by side in :attr:`Robots.q` / :attr:`Robots.qd`, robot ``r``'s at ``r.q_slice`` / ``r.dof_slice``), the mass
matrix of its tree (:func:`~cgp_core.robots.algorithms.mass_matrix`, the composite-rigid-body algorithm) and its
bias forces (:func:`~cgp_core.robots.algorithms.inverse_dynamics` with q̈ = 0: Coriolis, centrifugal, gravity).
Joints are exact by construction: a link's pose is a function of q, so no joint can stretch, whatever the mass
ratios.  Everything that constrains the joint velocities is a row of :mod:`cgp_core.robots.joint_solver`: joint
limits, drives bounded by the effort limit, mimic couplings, joint friction, and the **contacts of the links** —
with the ground, fixed bodies, free bodies and other links.

**Solved per robot.**  Every robot is solved on its own, with its own :class:`~.joint_solver.JointSolver` (its
warm-start memory), its M, bias, drives, properties and the contact rows of its links: the cost is linear in the
robots (a dense Cholesky of each robot's n × n, not of all robots' dofs at once).  Robots whose links touch each
other in a sub-step are an *island* (union-find over the link–link contacts between robots): such an island is
solved as one system, its block-diagonal M and its robots' rows together, their warm-start memories merged for the
solve and split again after it.  The robots whose links touch a free body in a sub-step are one such system too
(:class:`CoupledRobots`), solved in the body solver's loop (below).

Links are bodies of the world's :class:`~cgp_core.bodies.BodyModel` too (:mod:`.links`): the collision detector
finds their contacts like any body's, markers and contact reports show them, and their poses and momenta are
written from the robot's state after every sub-step (:meth:`Robots.write_bodies`).  In each sub-step
(:func:`cgp_core.dynamics.step_bodies`):

1. accumulate forces: wrench commands on links are taken out of the body accumulators (:meth:`take_wrenches`)
   and become joint efforts τ = Jᵀ F (the force at the link's COM and the torque);
2. detect contacts (the world's detector, links included);
3. **robot stage** (:meth:`solve`): the contacts that touch a link become rows in joint space (row Jacobian
   d·J(p) of the link's point p, minus the other link's if both sides are links; the free body on the other
   side, if any, takes part with its own mass, and its momenta get the equal and opposite impulses); the joint
   solver finds q̇ for the end of the sub-step — for the robots that touch no free body; the remaining contacts
   go on to the body solver, and the robots whose links touch a free body with them (:attr:`Robots.coupled`);
4. solve contacts between free bodies (the body solver) — with the coupled robots' rows in the same loop —,
   integrate bodies; integrate q (:func:`~cgp_core.robots.algorithms.integrate_positions`);

   (a robot whose ``joint_integrator`` is a Gauss–Legendre method has its smooth flow stepped first in step 3,
   :mod:`.joint_integrators`: the joint solver then takes the flow's velocity as an equivalent effort, and the
   position update adds the flow's own displacement);
5. write the link bodies' poses and momenta from q, q̇; move the free bodies the position stage pushed (out of
   the links, and in a sub-step where a link touches a free body out of each other too: :meth:`displace_free_bodies`).

A contact between a link and a free body is solved in ONE loop with the free bodies' own contacts
(:mod:`cgp_core.robots.coupled`, as Bullet's btMultiBody constraint solver): every sweep visits the robot rows and
the body rows on one shared velocity of the free bodies, so a link pushing a crate that the ground's friction
holds back (or a box resting on another box) converges within the sub-step, not over sub-steps.  The
penetration of both kinds of contacts is corrected in one position loop too (split impulses: the robot by
a pseudo-velocity, the free bodies by a displacement after the integrator; no energy added), so that a crate
squeezed between a link and a shelf is not pushed out of one into the other.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..limits import MAX_ROBOT_DOFS
from ..rotation import matrix_to_quat, quat_to_matrix
from ..scene.robots import RobotSpec
from . import algorithms
from .joint_integrators import DEFAULT_JOINT_INTEGRATOR, JOINT_INTEGRATORS, Collocation, smooth_steps
from .joint_solver import (
    KEY_SLOTS,
    ROW_DRIVE,
    ROW_EQUALITY,
    ROW_FRICTION,
    ROW_LIMIT,
    ROW_MIMIC,
    ROW_NORMAL,
    ROW_TANGENT,
    ROW_VELOCITY_LIMIT,
    link_contact_rows,
)
from .links import link_body_specs, link_name
from .model import (
    JOINT_FIXED_ROOT,
    JOINT_FLOATING,
    JOINT_PRISMATIC,
    JOINT_REVOLUTE,
    RobotStarts,
    neutral_positions,
    row_starts,
    stack_robot_arrays,
)


class RobotInstance:
    """One robot of a world: its model placed at its base pose, and where its coordinates live in the world's
    combined joint space.

    Attributes:
        name:        the robot's name (its links are ``<name>/<link>`` bodies).
        model:       the :class:`~cgp_core.robots.model.RobotModel`, root placed at the scene's base pose.
        arrays:      its compiled-kernel bundle (``model.arrays()``).
        q_slice, dof_slice: its positions / velocities in the world's ``q`` / ``qd``.
        spec:        the scene entry (:class:`~cgp_core.scene.robots.RobotSpec`).
    """

    def __init__(self, spec: RobotSpec, q_offset: int, dof_offset: int):
        self.name = spec.name
        self.spec = spec
        self.base_rotation = quat_to_matrix(np.asarray(spec.orientation, float)[None])[0]
        self.base_position = np.asarray(spec.position, float)
        self.model = place_root(spec.model, self.base_rotation, self.base_position)
        self.arrays = self.model.arrays
        #: the bundle as a plain tuple: what the compiled kernels are called with every sub-step (numba types a
        #: tuple faster than the NamedTuple), and by Python everywhere, so that each kernel compiles for one type
        self.kernel_arrays = tuple(self.arrays)
        self.q_slice = slice(q_offset, q_offset + self.model.n_q)
        self.dof_slice = slice(dof_offset, dof_offset + self.model.n_dofs)
        m = self.model
        #: (n_dofs,) the robot's own position index of each 1-dof joint's velocity (−1: a floating root's)
        self.q_of_dof = np.full(m.n_dofs, -1, np.int64)
        for b in range(len(m.body_names)):
            if int(m.joint_type[b]) in (JOINT_REVOLUTE, JOINT_PRISMATIC):
                self.q_of_dof[m.dof_start[b]] = m.q_start[b]
        self.has_coordinate = self.q_of_dof >= 0
        self.q_of_dof_clipped = np.maximum(self.q_of_dof, 0)
        from .joint_solver import JointProperties

        #: the joint solver's per-dof numbers and mimic couplings of this robot (its own dof indices)
        self.properties = JointProperties(*(np.ascontiguousarray(getattr(m, name), dtype=float) for name in (
            "lower", "upper", "effort_limit", "velocity_limit", "damping", "friction")),
            np.asarray(m.mimic_follower, np.int64).reshape(-1), np.asarray(m.mimic_leader, np.int64).reshape(-1),
            np.asarray(m.mimic_multiplier, float).reshape(-1), np.asarray(m.mimic_offset, float).reshape(-1),
            np.zeros((0, m.n_dofs)), np.zeros(0))  # a scene articulation's loop rows: set at each sub-step
        self.solver = None  # its JointSolver (warm-start memory), made at the first sub-step
        #: its joint-space integrator (cgp_core.robots.joint_integrators.JOINT_INTEGRATORS; the scene's
        #: ``joint_integrator``, None there: the default semi-implicit Euler step)
        self.joint_integrator = spec.joint_integrator or DEFAULT_JOINT_INTEGRATOR

    def initial_positions(self) -> np.ndarray:
        """(n_q,) the scene's initial joint positions (others at the neutral configuration)."""
        q = neutral_positions(self.model).astype(float)
        m = self.model
        if int(m.joint_type[0]) == JOINT_FLOATING:  # the base pose is the floating root's coordinates
            q[0:3] = self.base_position
            q[3:7] = np.asarray(self.spec.orientation, float)
        for joint, value in self.spec.joints.items():
            k = m.dof_names.index(joint) if joint in m.dof_names else None
            if k is None:
                continue
            body = int(np.searchsorted(m.dof_start, k, side="right") - 1)
            q[m.q_start[body] + (k - m.dof_start[body])] = value
        for f, lead, mult, off in zip(m.mimic_follower, m.mimic_leader, m.mimic_multiplier, m.mimic_offset):
            q[_q_index(m, int(f))] = mult * q[_q_index(m, int(lead))] + off
        return q


def place_root(model, rotation: np.ndarray, position: np.ndarray):
    """``model`` with a fixed root's joint frame moved to the base pose (``rotation`` (3, 3), ``position`` (3,) in
    the world): the robot stands where the scene puts it.  A floating root's pose is its coordinates instead."""
    from dataclasses import replace

    if int(model.joint_type[0]) == JOINT_FLOATING:
        return model
    joint_rotation = model.joint_rotation.copy()
    joint_position = model.joint_position.copy()
    joint_rotation[0] = rotation @ model.joint_rotation[0]
    joint_position[0] = rotation @ model.joint_position[0] + position
    return replace(model, joint_rotation=joint_rotation, joint_position=joint_position)


_NO_ROTATION = np.zeros((0, 3, 3))


class _Poses:
    """Every robot's body poses side by side, ``rotation`` (B, 3, 3) and ``position`` (B, 3) [m], robot ``k``'s at
    rows ``start[k]`` …; ``poses[k]`` is its ``(rotation, position)`` as views, made when asked (slicing them for
    every robot every sub-step cost ~30 µs at 64 robots, and most sub-steps ask for none)."""

    def __init__(self, rotation: np.ndarray, position: np.ndarray, start: np.ndarray):
        self.rotation, self.position, self.start = rotation, position, start

    def __len__(self) -> int:
        return len(self.start) - 1

    def __getitem__(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        a, b = self.start[k], self.start[k + 1]
        return self.rotation[a:b], self.position[a:b]

    def __iter__(self):
        return (self[k] for k in range(len(self)))


def _islands(count: int, robot_a: np.ndarray, robot_b: np.ndarray) -> tuple[np.ndarray, list[list[int]]]:
    """The robots joined by link–link contacts (``robot_a``, ``robot_b`` per contact, −1 for a side that is no
    link): ``(root (count,), groups)``, each robot's island representative (its smallest robot) and the islands
    as ascending lists of robots, ordered by their smallest robot.

    A union–find over the joining contacts, in Python: there are a handful of robots and, in the usual sub-step,
    no contact between two of them at all.  On the ``arm`` scene's contacts while its gripper pushes a box, timed
    side by side in one process (a busy machine): 9 µs a call, where scipy's ``connected_components`` with its
    sparse-matrix set-up took 440 µs (issue 37)."""
    root = np.arange(count, dtype=np.int64)
    between = np.flatnonzero((robot_a >= 0) & (robot_b >= 0) & (robot_a != robot_b))
    if not between.size:
        return root, [[k] for k in range(count)]
    parent = list(range(count))

    def find(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    for a, b in zip(robot_a[between].tolist(), robot_b[between].tolist()):
        ra, rb = find(a), find(b)
        if ra != rb:  # the smaller robot stays the root: every root is its island's smallest robot
            parent[max(ra, rb)] = min(ra, rb)
    groups: dict[int, list[int]] = {}
    for k in range(count):
        root[k] = find(k)
        groups.setdefault(int(root[k]), []).append(k)
    return root, list(groups.values())  # in order of their first (smallest) robot, each ascending


def _shift_keys(key: np.ndarray, dofs: int, mimics: int, equalities: int = 0) -> np.ndarray:
    """Warm-start keys (:data:`~.joint_solver.KEY_SLOTS`) of a robot moved ``dofs`` dofs, ``mimics`` mimic
    couplings and ``equalities`` loop rows along (negative: back): the dof rows' indices move, the contact rows'
    keys are the detector's."""
    kind = key // KEY_SLOTS
    shift = np.zeros(len(key), np.int64)
    shift[(kind == ROW_DRIVE) | (kind == ROW_FRICTION)] = dofs
    shift[(kind == ROW_VELOCITY_LIMIT) | (kind == ROW_LIMIT)] = 2 * dofs
    shift[kind == ROW_MIMIC] = mimics
    shift[kind == ROW_EQUALITY] = equalities
    return key + shift


def _merge_memories(parts):
    """One island's warm-start memory from its robots' (``(memory, dof offset, mimic offset, loop row offset)``
    each); a contact between two of them is in both, with the same impulse: kept once."""
    from .joint_solver import JointSolverMemory

    key = np.concatenate([_shift_keys(m.key, d, k, e) for m, d, k, e in parts])
    impulse = np.concatenate([m.impulse for m, _, _, _ in parts])
    key, first = np.unique(key, return_index=True)
    return JointSolverMemory(key, impulse[first])


def _split_memories(memory, parts, contact_key: np.ndarray, contact_robots: tuple[np.ndarray, np.ndarray]) -> dict:
    """Each robot's part of an island's memory: ``parts`` per robot ``(robot, dofs, n, mimics, k_mimic, equalities,
    k_equality)`` — its dofs ``dofs`` … ``dofs + n``, mimics and loop rows likewise, back in its own indices — and
    the rows of the contacts that touch its links (``contact_key`` (c,) the island's contacts' keys,
    ``contact_robots`` the robots of their sides A and B, −1 for a side that is no link: a link–link contact is in
    both robots' parts).  What is common to the robots is worked out once (per robot, an island of k robots cost
    k² in Python)."""
    from .joint_solver import JointSolverMemory

    kind, index = memory.key // KEY_SLOTS, memory.key % KEY_SLOTS
    dof = np.where((kind == ROW_VELOCITY_LIMIT) | (kind == ROW_LIMIT), index // 2, index)
    per_dof = (kind == ROW_DRIVE) | (kind == ROW_FRICTION) | (kind == ROW_VELOCITY_LIMIT) | (kind == ROW_LIMIT)
    mimic, equality = kind == ROW_MIMIC, kind == ROW_EQUALITY
    # each contact row's robots, from the contact of its key (keys are unique among a sub-step's contacts)
    robot_a = robot_b = np.full(len(kind), -1, np.int64)
    contact = np.flatnonzero((kind == ROW_NORMAL) | (kind == ROW_TANGENT))
    if contact.size and len(contact_key):
        order = np.argsort(contact_key, kind="stable")
        ordered = contact_key[order]
        at = np.minimum(np.searchsorted(ordered, index[contact] // 3), len(ordered) - 1)
        found = ordered[at] == index[contact] // 3
        robot_a, robot_b = robot_a.copy(), robot_b.copy()
        robot_a[contact[found]] = contact_robots[0][order[at[found]]]
        robot_b[contact[found]] = contact_robots[1][order[at[found]]]
    out = {}
    for robot, dofs, n, mimics, k_mimic, equalities, k_equality in parts:
        mine = per_dof & (dof >= dofs) & (dof < dofs + n)
        mine |= mimic & (index >= mimics) & (index < mimics + k_mimic)
        mine |= equality & (index >= equalities) & (index < equalities + k_equality)
        mine |= (robot_a == robot) | (robot_b == robot)
        key = _shift_keys(memory.key[mine], -dofs, -mimics, -equalities)
        o = np.argsort(key, kind="mergesort")
        out[robot] = JointSolverMemory(key[o], memory.impulse[mine][o])
    return out


class Island(NamedTuple):
    """Robots solved as one joint-space system in a sub-step (:meth:`Robots._island`): block-diagonal M, their rows
    side by side (robot ``k``'s dofs, mimic couplings and loop rows from its ``offsets``)."""

    group: list          # the robots, ascending
    system: tuple        # JointSystem of all their dofs
    properties: tuple    # JointProperties, the mimic dofs and the loop rows' columns shifted by the offsets
    drives: tuple        # JointDrives, concatenated
    rows: tuple          # ContactRows of the contacts ``selected`` (free bodies by their world body row)
    selected: object     # the ContactSet of their links' contacts, or None
    memory: tuple        # JointSolverMemory: theirs merged (cgp_core.robots.world._merge_memories)
    offsets: tuple       # (dof, mimic, loop row) offsets: three dicts robot → its first index there


def _q_index(model, dof: int) -> int:
    """The position index of a 1-dof joint's velocity index ``dof``."""
    body = int(np.searchsorted(model.dof_start, dof, side="right") - 1)
    return int(model.q_start[body] + (dof - model.dof_start[body]))


class Robots:
    """All robots of a world: their joint-space state side by side, each solved on its own (module docstring).

    Attributes (arrays of all robots side by side; robot ``r``'s part at ``r.q_slice`` / ``r.dof_slice``):
        q:          (n_q,) joint positions [rad, m; a floating root: position + quaternion xyzw].
        qd:         (n_dofs,) joint velocities [rad/s, m/s; a floating root: world-frame v, ω].
        effort:     (n_dofs,) the joint efforts [N m, N] applied in the last tick, averaged over its sub-steps.
        drives:     the joint solver's drive targets and gains (:class:`~cgp_core.robots.joint_solver.JointDrives`).
        body_robot, body_link: (n_bodies,) int64 per world body: the robot and the robot body it is, −1 for a
                    body that is not a moving link (set by :meth:`attach`).
        islands:    the last sub-step's groups of robots solved together (lists of robot indices; a robot alone
                    when no link of it touched another robot's); the groups that touched free bodies were moreover
                    solved as one system, in the body solver's loop (:attr:`coupled`, :mod:`.coupled`).
        coupled:    during a sub-step, between :meth:`solve` and the body solver: the robots whose links touch
                    free bodies (:class:`CoupledRobots`), or None.
    """

    def __init__(self, specs: list[RobotSpec]):
        self.robots: list[RobotInstance] = []
        q_offset = dof_offset = 0
        for spec in specs:
            robot = RobotInstance(spec, q_offset, dof_offset)
            if robot.model.n_dofs > MAX_ROBOT_DOFS:
                raise ValueError(f"robot {spec.name} has {robot.model.n_dofs} joint velocities; a robot has at most "
                                 f"{MAX_ROBOT_DOFS} (cgp_core.limits.MAX_ROBOT_DOFS)")
            self.robots.append(robot)
            q_offset += robot.model.n_q
            dof_offset += robot.model.n_dofs
        self.n_q, self.n_dofs = q_offset, dof_offset
        self.q0 = np.concatenate([r.initial_positions() for r in self.robots]) if self.robots else np.zeros(0)
        self.qd0 = np.zeros(self.n_dofs)
        for r in self.robots:  # a scene's jointed bodies start with their scene velocities (articulations)
            if r.spec.articulation is not None:
                self.qd0[r.dof_slice] = r.spec.articulation.velocity
        self._joint_limits = self._per_dof("lower", "upper", "effort_limit", "velocity_limit", "damping",
                                           "friction")
        self._mimic = self._mimic_rows()
        self.islands: list[list[int]] = [[k] for k in range(len(self.robots))]
        self._h = None
        self.body_robot = np.zeros(0, np.int64)
        self.body_link = np.zeros(0, np.int64)
        self._tally = None  # the contact report's sums over the tick (start_report ... finish_report)
        # the robots that touch nothing in a sub-step are stepped in one compiled call (joint_solver.
        # step_lone_robots), and all are integrated in one (algorithms.advance_all): every robot's arrays side by
        # side (concatenated: no per-robot lists at the border, see joint_solver.RobotStack), robot k's part at
        # its starts
        self._starts = RobotStarts(row_starts([r.model.n_bodies for r in self.robots]),
                                   row_starts([len(r.arrays.frame_body) for r in self.robots]),
                                   row_starts([r.model.n_dofs for r in self.robots]),
                                   row_starts([r.model.n_q for r in self.robots]),
                                   *(np.zeros(len(self.robots) + 1, np.int64) for _ in range(3)))  # _stack_properties
        self._q_start, self._dof_start, self._body_start = self._starts.q, self._starts.dof, self._starts.body
        self._q_of_local = (np.concatenate([r.q_of_dof for r in self.robots]) if self.robots
                            else np.zeros(0, np.int64))
        self._models = tuple(stack_robot_arrays([r.kernel_arrays for r in self.robots])) if self.robots else ()
        self._stack_properties()
        #: the robots with loop closures (scene articulations): their equality rows change every sub-step
        self._looped = [k for k, r in enumerate(self.robots)
                        if r.spec.articulation is not None and r.spec.articulation.loops]
        self._profile = None
        #: (n_bodies,) bool: the bodies being stepped this sub-step (None: all); set by the step before
        #: :meth:`solve` (cgp_core.dynamics.step_bodies): a robot whose links all sleep is not stepped
        self.active = None
        self._sleeping = np.zeros(len(self.robots), bool)
        self._commanded: set[int] = set()  # robots given a joint command since the last tick (they wake)
        self._joined = (np.zeros(0, np.int64), np.zeros(0, np.int64))
        #: the robots whose links touch free bodies this sub-step, for the body solver's loop (None: none)
        self.coupled = None
        self._body_displacement = None  # their position stage's free-body displacements (displace_free_bodies)
        #: the robots integrated by a Gauss–Legendre method (joint_integrators), by method: their smooth flow is
        #: stepped before the joint solver (solve); none: every robot takes the default step, unchanged
        self._smooth = {}
        for k, r in enumerate(self.robots):
            if JOINT_INTEGRATORS[r.joint_integrator] is not None:
                self._smooth.setdefault(r.joint_integrator, []).append(k)
        self._smooth = {name: np.array(robots, np.int64) for name, robots in self._smooth.items()}
        self._collocation = {}  # method name → its Collocation as a plain tuple, for the sub-step h
        #: (robots,) int64 per robot: the Gauss–Legendre passes (fixed-point and Newton) and the sub-steps that fell
        #: back to the default step (not converged even in joint_integrators.MAX_PIECES pieces), since it was made
        self.integrator_iterations = np.zeros(len(self.robots), np.int64)
        self.integrator_fallbacks = np.zeros(len(self.robots), np.int64)
        #: (robots,) int64: the sub-steps whose smooth flow took 2 to joint_integrators.MAX_PIECES Gauss–Legendre
        #: steps of h / pieces (the stages did not converge at h)
        self.integrator_subdivided = np.zeros(len(self.robots), np.int64)
        self._fallbacks_reported = np.zeros(len(self.robots), np.int64)
        self.reset()

    def __deepcopy__(self, memo):
        """A copy (the node's warm-up steps a throwaway copy of the world) whose robots' drives are views of the
        copied :attr:`drives` again, as commands need (a deep copy of a view is no view)."""
        import copy

        new = type(self).__new__(type(self))
        memo[id(self)] = new
        for key, value in self.__dict__.items():
            new.__dict__[key] = copy.deepcopy(value, memo)
        new.drives = new._drives
        return new

    def _stack_properties(self) -> None:
        """Every robot's joint properties side by side, as :func:`~.joint_solver.step_lone_robots` takes them, and
        the starts of their mimic couplings and equality rows (again whenever a robot's loop rows change)."""
        from .joint_solver import stack_properties

        if not self.robots:
            self._properties = ()
            return
        properties, mimic, equality, entry = stack_properties([r.properties for r in self.robots])
        self._properties = tuple(properties)
        self._starts = self._starts._replace(mimic=mimic, equality=equality, equality_entry=entry)

    def _memory(self, k: int):
        """Robot ``k``'s warm-start memory (:class:`~.joint_solver.JointSolverMemory`, copies)."""
        from .joint_solver import JointSolverMemory

        a, b = self._memories.start[k], self._memories.start[k + 1]
        return JointSolverMemory(self._memories.key[a:b].copy(), self._memories.impulse[a:b].copy())

    def _set_memory(self, k: int, memory) -> None:
        """Robot ``k``'s warm-start memory replaced (the others' kept; one concatenation of all)."""
        self._set_memories({k: memory})

    def _set_memories(self, memories: dict) -> None:
        """The warm-start memories of the robots ``memories`` (robot → its memory) replaced, the others' kept: one
        concatenation of all (per robot, an island of k robots was k concatenations of every robot's)."""
        from .joint_solver import RobotMemories

        old = self._memories
        parts = [(memories[j].key, memories[j].impulse) if j in memories else
                 (old.key[old.start[j]:old.start[j + 1]], old.impulse[old.start[j]:old.start[j + 1]])
                 for j in range(len(self.robots))]
        start = row_starts([len(key) for key, _ in parts])
        self._memories = RobotMemories(np.concatenate([key for key, _ in parts]).astype(np.int64),
                                       np.concatenate([impulse for _, impulse in parts]).astype(float), start)

    # ---- robots added and removed at run time (World.spawn / World.delete) ------------------------------------

    def with_robot(self, spec: RobotSpec) -> Robots:
        """A new :class:`Robots` with ``spec``'s robot appended (its coordinates last in the combined joint space,
        at its initial positions, at rest, its drives holding them if ``hold``); every robot already here keeps
        its joint positions, velocities, efforts, drives (commands included) and pending wrench torques.  The
        joint solver starts cold (its warm start is per contact point of the old joint space).  ValueError past
        a robot past MAX_ROBOT_DOFS (cgp_core.limits); call :meth:`attach` with the new body model."""
        return self._carried([r.spec for r in self.robots] + [spec])

    def without(self, name: str) -> Robots | None:
        """A new :class:`Robots` without robot ``name`` (the others' coordinates shifted down, their state carried
        over as in :meth:`with_robot`), or None if it was the last one."""
        self.robot(name)  # KeyError if unknown
        specs = [r.spec for r in self.robots if r.name != name]
        return self._carried(specs) if specs else None

    def _carried(self, specs: list[RobotSpec]) -> Robots:
        new = Robots(specs)
        old = {r.name: r for r in self.robots}
        for r in new.robots:
            was = old.get(r.name)
            if was is None or was.spec is not r.spec:
                continue
            new.q[r.q_slice] = self.q[was.q_slice]
            for attribute in ("qd", "effort", "_effort_sum", "_wrench_torque", "_pseudo"):
                getattr(new, attribute)[r.dof_slice] = getattr(self, attribute)[was.dof_slice]
            for field, before in zip(new.drives, self.drives):
                field[r.dof_slice] = before[was.dof_slice]
        new._substeps = self._substeps
        new.prepare()
        return new

    # ---- building ---------------------------------------------------------------------------------------

    def _per_dof(self, *names) -> dict:
        return {name: (np.concatenate([getattr(r.model, name) for r in self.robots]).astype(float)
                       if self.robots else np.zeros(0)) for name in names}

    def _mimic_rows(self):
        follower, leader, mult, off = [], [], [], []
        for r in self.robots:
            base = r.dof_slice.start
            follower += list(np.asarray(r.model.mimic_follower) + base)
            leader += list(np.asarray(r.model.mimic_leader) + base)
            mult += list(r.model.mimic_multiplier)
            off += list(r.model.mimic_offset)
        return (np.array(follower, np.int64), np.array(leader, np.int64), np.array(mult, float),
                np.array(off, float))

    def body_specs(self) -> list:
        """The world bodies of every robot's links at the initial positions (:func:`.links.link_body_specs`)."""
        specs = []
        for r in self.robots:
            if r.spec.articulation is not None:  # its links are the scene's own bodies
                continue
            rotation, position = algorithms.forward_kinematics(r.kernel_arrays, self.q0[r.q_slice])
            found, _ = link_body_specs(r.model, r.name, rotation, position, friction=r.spec.friction,
                                       restitution=r.spec.restitution)
            specs += found
        return specs

    def names(self) -> list[str]:
        return [r.name for r in self.robots]

    def robot(self, name: str) -> RobotInstance:
        for r in self.robots:
            if r.name == name:
                return r
        raise KeyError(f"no robot named {name!r} (robots: {', '.join(self.names()) or 'none'})")

    def attach(self, body_model) -> None:
        """Find each robot body's world body row by name (after any change of the world's bodies)."""
        n = body_model.count
        self.body_robot = np.full(n, -1, np.int64)
        self.body_link = np.full(n, -1, np.int64)
        self.self_collision_group = np.full(n, -1, np.int64)
        index = {name: i for i, name in enumerate(body_model.names)}
        for k, r in enumerate(self.robots):
            if r.spec.articulation is not None:  # the fixed bodies its joints hang from: jointed, no contacts
                for name in r.spec.articulation.fixed_parents:
                    if name in index:
                        self.self_collision_group[index[name]] = k
            for b, link in enumerate(r.model.body_names):
                row = index.get(self._body_name(r, link))
                if row is None:
                    continue
                self.self_collision_group[row] = k
                if not body_model.fixed[row]:
                    self.body_robot[row], self.body_link[row] = k, b
        # the pairs the robot stage would drop: never tested by the detector (Detector.exclude)
        jointed = np.full(n, -1, np.int64)
        for r in self.robots:
            rows = {b: index.get(self._body_name(r, link)) for b, link in enumerate(r.model.body_names)}
            for b, row in rows.items():
                parent = int(r.model.parent[b])
                if row is not None and parent >= 0 and rows.get(parent) is not None:
                    jointed[row] = rows[parent]
        self.exclusion = (self.self_collision_group, jointed,
                          np.array([r.spec.self_collision for r in self.robots], bool))
        # per robot: its moving link bodies' world rows and robot bodies (write_bodies, take_wrenches)
        self._link_rows = np.flatnonzero(self.body_robot >= 0)
        self._robot_rows = [np.flatnonzero(self.body_robot == k) for k in range(len(self.robots))]
        self._robot_links = [self.body_link[rows] for rows in self._robot_rows]
        self._all_rows = np.concatenate(self._robot_rows) if self.robots else np.zeros(0, np.int64)
        #: (robots,) each robot's moving links
        self._link_count = np.array([rows.size for rows in self._robot_rows], np.int64)
        #: each moving link's robot body in the robots' bodies side by side (advance_all's rows)
        self._all_link_index = (np.concatenate([self._body_start[k] + links for k, links in
                                                enumerate(self._robot_links)]).astype(np.int64)
                                if self.robots else np.zeros(0, np.int64))
        self._all_com = np.concatenate([r.model.com[links] for r, links in zip(self.robots, self._robot_links)]) \
            if self.robots else np.zeros((0, 3))
        self._all_inertia = np.ascontiguousarray(body_model.inertia_body[self._all_rows])
        self._all_mass_flat = np.ascontiguousarray(body_model.mass[self._all_rows], dtype=float)
        # each robot's moving links joined to its first one: one sleep island (joined_pairs)
        pairs = [(np.full(len(rows) - 1, rows[0], np.int64), rows[1:].astype(np.int64))
                 for rows in self._robot_rows if len(rows) > 1]
        self._joined = ((np.concatenate([a for a, _ in pairs]), np.concatenate([b for _, b in pairs])) if pairs
                        else (np.zeros(0, np.int64), np.zeros(0, np.int64)))

    # ---- sleeping (cgp_core.sleep): a robot's links are one island ----------------------------------------------

    def joined_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """``(a (k,), b (k,))`` world body rows held together by joints — every moving link of a robot (or of a
        scene's articulation) with its first one —, which :meth:`cgp_core.sleep.Islands.update` puts in one
        island whether they touch or not."""
        return self._joined

    def take_commanded(self) -> np.ndarray:
        """The moving link rows of the robots commanded (:meth:`command`) since the last call: their islands wake."""
        commanded, self._commanded = self._commanded, set()
        rows = [self._robot_rows[k] for k in sorted(commanded) if k < len(getattr(self, "_robot_rows", ()))]
        return np.concatenate(rows).astype(np.int64) if rows else np.zeros(0, np.int64)

    def _sleepers(self) -> np.ndarray:
        """(robots,) bool: the robots whose moving links all sleep (``active`` False for every one)."""
        active = self.active
        if active is None or not hasattr(self, "_robot_rows"):
            return np.zeros(len(self.robots), bool)
        rows = self._all_rows
        awake = np.bincount(self.body_robot[rows[active[rows]]], minlength=len(self.robots))
        return (self._link_count > 0) & (awake == 0)

    def hold_sleeping(self, awake: np.ndarray) -> None:
        """After the islands' update: the robots whose links all fell asleep (``awake`` (n_bodies,) False) keep
        their joint positions at zero joint velocity (their link momenta were zeroed with them)."""
        self.active = awake
        self._sleeping = self._sleepers()
        for k in np.flatnonzero(self._sleeping):
            r = self.robots[k]
            self.qd[r.dof_slice] = 0.0
            self._pseudo[r.dof_slice] = 0.0

    @staticmethod
    def _body_name(r: RobotInstance, link: str) -> str:
        """The world body of robot ``r``'s body ``link``: ``<robot>/<link>``, or the scene body's own name for an
        articulation of jointed scene bodies."""
        return link if r.spec.articulation is not None else link_name(r.name, link)

    def reset(self) -> None:
        self.q = self.q0.copy()
        self.qd = self.qd0.copy()
        self.effort = np.zeros(self.n_dofs)
        self._effort_sum = np.zeros(self.n_dofs)
        self._substeps = 0
        for r in self.robots:
            if r.solver is not None:
                r.solver.reset()
        from .joint_solver import RobotMemories

        self._memories = RobotMemories.empty(len(self.robots))
        self.drives = self._initial_drives()
        self._wrench_torque = np.zeros(self.n_dofs)
        self._pseudo = np.zeros(self.n_dofs)
        self._flow_displacement = np.zeros(self.n_dofs)  # Gauss–Legendre: the flow's D (joint_integrators)
        self._collocated = np.zeros(self.n_dofs)  # Gauss–Legendre: the flow's velocity qd_c
        self._stepped = np.zeros(self.n_dofs, bool)  # the dofs of robots whose flow was stepped this sub-step
        self.prepare()

    @property
    def drives(self):
        return self._drives

    @drives.setter
    def drives(self, drives) -> None:
        """The drives of all robots; each robot solves with views of its part (commands write through them)."""
        self._drives = drives
        for r in self.robots:
            r.drives = tuple(a[r.dof_slice] for a in drives)

    def _initial_drives(self):
        """Position drives holding the initial positions on every movable joint of a robot with ``hold``
        (mimic followers excepted: their coupling row moves them)."""
        from .joint_solver import DRIVE_NONE, DRIVE_POSITION, JointDrives

        drives = JointDrives.none(self.n_dofs)
        followers = set(self._mimic[0].tolist())
        for r in self.robots:
            if not r.spec.hold:
                continue
            m = r.model
            for k in range(m.n_dofs):
                dof = r.dof_slice.start + k
                body = int(np.searchsorted(m.dof_start, k, side="right") - 1)
                if int(m.joint_type[body]) not in (JOINT_REVOLUTE, JOINT_PRISMATIC) or dof in followers:
                    continue
                drives.mode[dof] = DRIVE_POSITION
                drives.target_position[dof] = self.q0[_q_index(m, k) + r.q_slice.start]
                drives.stiffness[dof] = r.spec.stiffness
                drives.damping[dof] = r.spec.damping
        assert DRIVE_NONE == 0
        self._articulation_drives(drives)
        return drives

    def _articulation_drives(self, drives) -> None:
        """The drives of a scene's joints (``joints[].drive``) on the articulations' dofs."""
        from .joint_solver import DRIVE_EFFORT, DRIVE_POSITION, DRIVE_VELOCITY

        modes = {"position": DRIVE_POSITION, "velocity": DRIVE_VELOCITY, "effort": DRIVE_EFFORT}
        for r in self.robots:
            if r.spec.articulation is None:
                continue
            for joint, drive in r.spec.articulation.drives.items():
                dof = r.dof_slice.start + r.model.dof_names.index(joint)
                mode = modes[drive["mode"]]
                drives.mode[dof] = mode
                drives.stiffness[dof] = drive["stiffness"] if mode == DRIVE_POSITION else 0.0
                drives.damping[dof] = drive["damping"] if mode != DRIVE_EFFORT else 0.0
                if mode == DRIVE_POSITION:
                    drives.target_position[dof] = drive["target"]
                elif mode == DRIVE_VELOCITY:
                    drives.target_velocity[dof] = drive["target"]
                else:
                    drives.target_effort[dof] = drive["target"]

    # ---- the robot stage ----------------------------------------------------------------------------------

    def take_wrenches(self, body_model, state) -> None:
        """Wrench commands accumulated on link bodies (before gravity is added) → joint efforts τ = Jᵀ F: the
        force at the link's COM and the torque, through the link's point and angular Jacobians; the link rows'
        accumulators are cleared (a link moves by its joints only)."""
        self._wrench_torque[:] = 0.0
        rows = self._link_rows
        if not rows.size:
            return
        F, T = state.force[rows], state.torque[rows]
        if not (F.any() or T.any()):  # no wrench on a link (the usual case)
            return
        loaded = np.flatnonzero((F != 0.0).any(axis=1) | (T != 0.0).any(axis=1))
        for i in loaded:
            row = rows[i]
            r = self.robots[self.body_robot[row]]
            link = int(self.body_link[row])
            rotation, position = self._poses[self.body_robot[row]]
            com = state.position[row]
            Jp = algorithms.point_jacobian(r.kernel_arrays, rotation, position, link, com)
            Jw = algorithms.angular_jacobian(r.kernel_arrays, rotation, position, link)
            self._wrench_torque[r.dof_slice] += Jp.T @ F[i] + Jw.T @ T[i]
        if loaded.size:
            state.force[rows] = 0.0
            state.torque[rows] = 0.0

    def prepare(self) -> None:
        """The body poses of every robot at the current q (cached for the sub-step), side by side as
        :meth:`integrate` leaves them (:class:`_Poses`)."""
        self._velocities = None
        poses = [algorithms.forward_kinematics(r.kernel_arrays, self.q[r.q_slice]) for r in self.robots]
        rotation = np.concatenate([R for R, _ in poses]) if poses else np.zeros((0, 3, 3))
        position = np.concatenate([x for _, x in poses]) if poses else np.zeros((0, 3))
        self._poses = _Poses(rotation, position, self._body_start)
        self._loop_rows()

    def _loop_rows(self) -> None:
        """The articulations' loop closures at the current q, as their joint solver's equality rows (three per
        loop: :meth:`cgp_core.robots.articulations.LoopClosure.rows`), in each robot's own dofs."""
        for k in self._looped:
            r = self.robots[k]
            rotation, position = self._poses[k]
            rows = [loop.rows(r.arrays, rotation, position) for loop in r.spec.articulation.loops]
            jacobian = np.ascontiguousarray(np.vstack([j for j, _ in rows]))
            error = np.ascontiguousarray(np.concatenate([c for _, c in rows]))
            r.properties = r.properties._replace(equality_jacobian=jacobian, equality_error=error)
        if self._looped:
            self._stack_properties()

    def loop_errors(self) -> dict[str, float]:
        """Every loop-closing joint's error |p_a − p_b| [m] at the current q, by joint name."""
        out = {}
        for k in self._looped:
            r = self.robots[k]
            rotation, position = algorithms.forward_kinematics(r.kernel_arrays, self.q[r.q_slice])
            for loop in r.spec.articulation.loops:
                pa, pb = loop.points(rotation, position)
                out[loop.name] = float(np.linalg.norm(pa - pb))
        return out

    def solve(self, contacts, body_model, state, h: float, gravity):
        """The robot stage (module docstring, step 3): every robot, or island of robots whose links touch, solved
        on its own — except the robots whose links touch a free body, which are prepared as one joint-space system
        in :attr:`coupled` (None when there are none) for the body solver's loop; returns the contacts left for
        the body solver."""
        from .joint_solver import FreeBodies, JointSolver, JointSystem

        if contacts.count:
            a, b = contacts.body_a, contacts.body_b
            robot_a = np.where(a >= 0, self.body_robot[np.maximum(a, 0)], -1)
            robot_b = self.body_robot[b]
            link_side_a, link_side_b = robot_a >= 0, robot_b >= 0
            ours = link_side_a | link_side_b
        else:
            ours = np.zeros(0, bool)
        if ours.any():
            keep = self._contact_filter(contacts, link_side_a, link_side_b)
            ours &= keep
            rest = contacts.select(np.flatnonzero(~ours & keep))
            chosen = np.flatnonzero(ours)
        else:
            rest, chosen = contacts, np.zeros(0, np.int64)
        if self._h != h:  # a new sub-step length: new solvers, the warm-start memories kept
            from .joint_solver import JointSettings

            for r in self.robots:
                memory = r.solver.memory if r.solver is not None else None
                r.solver = JointSolver(h, check=False)
                if memory is not None:
                    r.solver.memory = memory
            self._h = h
            self._settings = tuple(JointSettings.default(h))
        gravity = np.asarray(gravity, float)
        # which robot each chosen contact belongs to; robots joined by a link–link contact form an island
        owner = {}  # island root → its contacts (indices into ``contacts``, in the detector's order)
        if chosen.size:
            ra, rb = robot_a[chosen], robot_b[chosen]
            root, groups = _islands(len(self.robots), ra, rb)
            island_of = np.where(rb >= 0, root[np.maximum(rb, 0)], root[np.maximum(ra, 0)])
            order = np.argsort(island_of, kind="stable")
            bounds = np.searchsorted(island_of[order], np.arange(len(self.robots) + 1))
            for k in range(len(self.robots)):
                if bounds[k + 1] > bounds[k]:
                    owner[k] = chosen[order[bounds[k]:bounds[k + 1]]]
        else:
            root, groups = None, [[k] for k in range(len(self.robots))]
        self.islands = groups
        self._sleeping = sleeping = self._sleepers()
        for k in np.flatnonzero(sleeping):  # not stepped: q kept (no velocity, no position-stage push)
            r = self.robots[k]
            self.qd[r.dof_slice] = 0.0
            self._pseudo[r.dof_slice] = 0.0
        # the joint efforts the solver takes (also _solve_island's): the wrench torques, or a Gauss–Legendre robot's
        # equivalent effort
        self._applied = applied = self._smooth_step(h, gravity, sleeping) if self._smooth else self._wrench_torque
        if root is None:  # no link touches anything (the usual case): every robot awake is stepped below
            lone = np.flatnonzero(~sleeping)
        else:
            lone = np.array([g[0] for g in groups if len(g) == 1 and int(root[g[0]]) not in owner
                             and not sleeping[g[0]]], np.int64)
        if lone.size:
            from .joint_solver import RobotMemories, step_lone_robots

            if self._profile is None:
                self._profile = self.robots[0].solver.profile
            self._memories = RobotMemories(*step_lone_robots(
                lone, (self._models, self._properties, tuple(self._drives)), tuple(self._memories),
                (self.q, self.qd, applied, self._pseudo, self._effort_sum, self._q_of_local),
                tuple(self._starts), gravity, self._settings, self._profile.seconds))
            self._profile.calls += 1
        self.coupled = None
        coupled_robots, coupled_contacts = [], []
        for group in groups if root is not None else ():
            if len(group) == 1 and int(root[group[0]]) not in owner:
                continue  # stepped above (or asleep)
            picked = owner.get(int(root[group[0]]))
            if picked is not None and picked.size and self._touches_free_body(contacts, picked, body_model):
                # its rows share free bodies with the body solver's: solved in its loop (cgp_core.robots.coupled)
                coupled_robots += group
                coupled_contacts.append(picked)
                continue
            selected = contacts.select(picked) if picked is not None and picked.size else None
            if len(group) == 1:
                r = self.robots[group[0]]
                q, qd = self.q[r.q_slice], self.qd[r.dof_slice]
                M, bias = algorithms.joint_space_terms(r.kernel_arrays, q, qd, gravity)
                coordinate = np.where(r.has_coordinate, q[r.q_of_dof_clipped], 0.0)
                system = JointSystem(M, bias, applied[r.dof_slice].copy(), coordinate, qd.copy())
                rows = self._contact_rows(selected, body_model, state, {group[0]: 0}, r.model.n_dofs)
                r.solver.memory = self._memory(group[0])
                step = r.solver.step(system, r.properties, r.drives, rows, FreeBodies.empty())
                self._set_memory(group[0], r.solver.memory)
                self._finish(group, step, rows, selected, state)
            else:
                self._solve_island(group, selected, body_model, state, gravity)
        if coupled_robots:
            # every robot touching a free body in one joint-space system (block-diagonal M): one loop with the
            # body rows needs one set of robot rows
            selected = contacts.select(np.sort(np.concatenate(coupled_contacts)))
            self.coupled = CoupledRobots(self, self._island(sorted(coupled_robots), selected, body_model, state,
                                                            gravity), state)
        self._substeps += 1
        return rest

    def _touches_free_body(self, contacts, picked: np.ndarray, body_model) -> bool:
        """Whether one of the contacts ``picked`` has a free body (awake, movable, no link) on a side."""
        return bool(self._free_side(contacts.body_a[picked], body_model).any()
                    or self._free_side(contacts.body_b[picked], body_model).any())

    def _free_side(self, side: np.ndarray, body_model) -> np.ndarray:
        """(k,) bool: the bodies ``side`` (−1: the ground) that are free bodies the contact rows move: not a link,
        movable, awake (a sleeping body is static to the robots, as to the body solver)."""
        row = np.maximum(side, 0)
        free = (side >= 0) & (self.body_robot[row] < 0) & (body_model.inv_mass[row] > 0.0)
        return free if self.active is None else free & self.active[row]

    def _smooth_step(self, h: float, gravity: np.ndarray, sleeping: np.ndarray) -> np.ndarray:
        """The smooth flow of the awake robots integrated by a Gauss–Legendre method, before the joint solver
        (:mod:`.joint_integrators`): returns the applied joint efforts (n_dofs,) the solver takes — the wrench
        torques, each such robot's replaced by its equivalent effort —, and keeps the flow's velocity and
        displacement for the position update (:meth:`integrate` ends it)."""
        applied = self._wrench_torque.copy()
        self._collocated = np.zeros(self.n_dofs)
        self._flow_displacement = np.zeros(self.n_dofs)
        self._stepped = np.zeros(self.n_dofs, bool)
        for name, robots in self._smooth.items():
            which = robots[~sleeping[robots]]
            if not which.size:
                continue
            method = self._collocation.get(name)
            if method is None or method[2] != h:
                method = self._collocation[name] = tuple(Collocation.named(name, h))
            smooth_steps(which, self._models, tuple(self._starts),
                         (self.q, self.qd, applied, self._collocated, self._flow_displacement, self._stepped,
                          self.integrator_iterations, self.integrator_subdivided, self.integrator_fallbacks),
                         gravity, method)
        return applied

    def take_fallbacks(self) -> list[tuple[str, int]]:
        """The robots whose Gauss–Legendre step fell back to the default step since the last call, with how many
        sub-steps did (the World reports them as events)."""
        new = self.integrator_fallbacks - self._fallbacks_reported
        self._fallbacks_reported = self.integrator_fallbacks.copy()
        return [(self.robots[k].name, int(new[k])) for k in np.flatnonzero(new)]

    def _finish(self, group, step, rows, selected, state) -> None:
        """Write an island's step: q̇, the pseudo-velocity, the effort; the contact report's sums."""
        offset = 0
        for k in group:
            r = self.robots[k]
            n = r.model.n_dofs
            self.qd[r.dof_slice] = step.velocity[offset:offset + n]
            self._pseudo[r.dof_slice] = step.pseudo_velocity[offset:offset + n]
            self._effort_sum[r.dof_slice] += step.effort[offset:offset + n]
            offset += n
        if self._tally is not None and selected is not None and selected.count:
            self._tally_contacts(selected, rows, step.contact_impulse, state)

    def _island(self, group, selected, body_model, state, gravity) -> Island:
        """The joint-space problem of robots ``group`` solved as one system (block-diagonal M) with the contacts
        ``selected`` (None: none) of their links: their warm-start memories merged."""
        from .joint_solver import JointProperties, JointSystem

        offsets, mimic_offsets, equality_offsets = {}, {}, {}
        n = k_mimic = k_equality = 0
        for k in group:
            offsets[k], mimic_offsets[k], equality_offsets[k] = n, k_mimic, k_equality
            n += self.robots[k].model.n_dofs
            k_mimic += len(self.robots[k].properties.mimic_follower)
            k_equality += len(self.robots[k].properties.equality_error)
        M = np.zeros((n, n))
        bias, applied, coordinate, qd = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
        for k in group:
            r = self.robots[k]
            s = slice(offsets[k], offsets[k] + r.model.n_dofs)
            q = self.q[r.q_slice]
            M[s, s], bias[s] = algorithms.joint_space_terms(r.kernel_arrays, q, self.qd[r.dof_slice], gravity)
            applied[s] = self._applied[r.dof_slice]
            coordinate[s] = np.where(r.has_coordinate, q[r.q_of_dof_clipped], 0.0)
            qd[s] = self.qd[r.dof_slice]
        parts = [self.robots[k].properties for k in group]
        properties = JointProperties(*(np.concatenate([getattr(p, name) for p in parts]) for name in (
            "lower", "upper", "effort_limit", "velocity_limit", "damping", "friction")),
            np.concatenate([p.mimic_follower + offsets[k] for p, k in zip(parts, group)]),
            np.concatenate([p.mimic_leader + offsets[k] for p, k in zip(parts, group)]),
            np.concatenate([p.mimic_multiplier for p in parts]), np.concatenate([p.mimic_offset for p in parts]),
            np.zeros((k_equality, n)), np.concatenate([p.equality_error for p in parts]))
        for p, k in zip(parts, group):  # each robot's loop rows in its own columns (block-diagonal)
            e0, n0 = equality_offsets[k], offsets[k]
            properties.equality_jacobian[e0:e0 + len(p.equality_error), n0:n0 + p.equality_jacobian.shape[1]] = \
                p.equality_jacobian
        drives = tuple(np.concatenate([self.robots[k].drives[i] for k in group]) for i in range(6))
        memory = self._memory(group[0]) if len(group) == 1 else _merge_memories(
            [(self._memory(k), offsets[k], mimic_offsets[k], equality_offsets[k]) for k in group])
        return Island(group, JointSystem(M, bias, applied, coordinate, qd), properties, drives,
                      self._contact_rows(selected, body_model, state, offsets, n), selected, memory,
                      (offsets, mimic_offsets, equality_offsets))

    def _island_solved(self, island: Island, step, memory, seconds: np.ndarray, state) -> None:
        """An island's step written back: each robot's part of the memory (split again), of the stage times
        ``seconds``, its q̇, pseudo-velocity and effort, the contact report's sums."""
        offsets, mimic_offsets, equality_offsets = island.offsets
        selected, rows = island.selected, island.rows
        if len(island.group) == 1:  # its own memory, nothing to split
            k = island.group[0]
            self._set_memory(k, memory)
            self.robots[k].solver.profile.seconds += seconds
            self._finish(island.group, step, rows, selected, state)
            return
        # each contact's robots: the links' on either side (a link–link contact is in both robots' memories)
        if selected is not None:
            key = rows.key
            sides = tuple(np.where(side >= 0, self.body_robot[np.maximum(side, 0)], -1)
                          for side in (selected.body_a, selected.body_b))
        else:
            key, sides = np.zeros(0, np.int64), (np.zeros(0, np.int64), np.zeros(0, np.int64))
        parts = _split_memories(memory, [(k, offsets[k], self.robots[k].model.n_dofs, mimic_offsets[k],
                                          len(self.robots[k].properties.mimic_follower), equality_offsets[k],
                                          len(self.robots[k].properties.equality_error)) for k in island.group],
                                key, sides)
        for k in island.group:
            self.robots[k].solver.profile.seconds += seconds / len(island.group)
        self._set_memories(parts)
        self._finish(island.group, step, rows, selected, state)

    def _solve_island(self, group, selected, body_model, state, gravity) -> None:
        """Robots whose links touch each other (and no free body) in this sub-step: one joint-space system of all
        their dofs (:meth:`_island`), solved on its own."""
        from .joint_solver import FreeBodies, JointSolver

        island = self._island(group, selected, body_model, state, gravity)
        solver = JointSolver(self._h, check=False)
        solver.memory = island.memory
        step = solver.step(island.system, island.properties, island.drives, island.rows, FreeBodies.empty())
        self._island_solved(island, step, solver.memory, solver.profile.seconds, state)

    def displace_free_bodies(self, body_model, state) -> None:
        """After the integrator: move the free bodies the position stage pushed (the links' contacts; with the
        contacts between free bodies too in a coupled sub-step, :func:`~.coupled.relax_together`) by their
        displacement (:attr:`~.joint_solver.JointStep.body_displacement`), positions and orientations only — the
        angular momentum turned with the body, so that neither momentum nor kinetic energy changes (split
        impulses, as the body solver's penetration recovery)."""
        displacement, self._body_displacement = getattr(self, "_body_displacement", None), None
        if displacement is None:
            return
        moved = np.flatnonzero(np.abs(displacement[:body_model.count]).max(axis=1) > 0.0)
        if not moved.size:
            return
        from ..rotation import quat_from_rotvec, quat_multiply, quat_normalize, quat_rotate

        state.position[moved] += displacement[moved, :3]
        turn = quat_from_rotvec(displacement[moved, 3:])
        state.orientation[moved] = quat_normalize(quat_multiply(turn, state.orientation[moved]))
        state.angular_momentum[moved] = quat_rotate(turn, state.angular_momentum[moved])
        if state.rotation is not None:  # an integrator that keeps its own matrix (explicit Euler)
            state.rotation[moved] = quat_to_matrix(turn) @ state.rotation[moved]

    def _q_of_dof(self) -> np.ndarray:
        """(n_dofs,) the position index of every 1-dof joint's velocity (−1 for a floating root's)."""
        if not hasattr(self, "_q_of_dof_cache"):
            out = np.full(self.n_dofs, -1, np.int64)
            for r in self.robots:
                out[r.dof_slice] = np.where(r.q_of_dof >= 0, r.q_of_dof + r.q_slice.start, -1)
            self._q_of_dof_cache = out
        return self._q_of_dof_cache

    def _contact_filter(self, contacts, side_a, side_b) -> np.ndarray:
        keep = np.ones(contacts.count, bool)
        both = np.flatnonzero(side_a & side_b)
        for c in both:
            a, b = int(contacts.body_a[c]), int(contacts.body_b[c])
            ra, rb = int(self.body_robot[a]), int(self.body_robot[b])
            if ra != rb:
                continue
            r = self.robots[ra]
            la, lb = int(self.body_link[a]), int(self.body_link[b])
            parent = r.model.parent
            if not r.spec.self_collision or parent[la] == lb or parent[lb] == la:
                keep[c] = False
            elif r.spec.articulation is not None and (min(la, lb), max(la, lb)) in r.spec.articulation.loop_pairs:
                keep[c] = False  # the two bodies of a loop-closing joint: jointed too
        # a link against its robot's fixed root: the root is a fixed body, jointed to the first links
        fixed_a = np.flatnonzero(side_b & ~side_a & (contacts.body_a >= 0))
        for c in fixed_a:
            a, b = int(contacts.body_a[c]), int(contacts.body_b[c])
            group = self.self_collision_group[a]
            if group >= 0 and group == self.body_robot[b]:
                r = self.robots[group]
                if not r.spec.self_collision or r.model.parent[int(self.body_link[b])] == 0:
                    keep[c] = False
        return keep

    def _contact_rows(self, contacts, body_model, state, offsets: dict, n: int):
        """Rows in the joint space of an island (``offsets``: robot → its first dof there; ``n`` dofs) for the
        contacts that touch its links (module docstring, step 3): per point the three directions (n, t₁, t₂) of the
        contact solver; each row is the velocity of side B relative to side A along the direction, its impulse
        pushes B along it and A against it."""
        from .joint_solver import ContactRows

        if contacts is None or not contacts.count:
            return ContactRows.empty(n)
        in_island = np.full(len(self.robots), -1, np.int64)
        for k, start in offsets.items():
            in_island[k] = start
        J, body, body_jacobian = link_contact_rows(
            (self._models, tuple(self._starts), self._poses.rotation, self._poses.position), (in_island, n),
            (self.body_robot, self.body_link, state.position),
            (contacts.body_a, contacts.body_b, contacts.point, contacts.normal,
             self._free_side(contacts.body_a, body_model), self._free_side(contacts.body_b, body_model)))
        return ContactRows(J, body, body_jacobian, contacts.separation.copy(), contacts.friction.copy(),
                           contacts.key % (1 << 37))

    # ---- the contact report (cgp_core.solver.report): the link contacts solved here --------------------------

    def start_report(self, bodies: int) -> None:
        """Sum the robot stage's contacts over the tick's sub-steps (the world's :attr:`report_contacts`)."""
        self._tally = {"body_impulse": np.zeros((bodies, 6)), "touched": np.zeros(bodies, bool), "steps": []}

    def _tally_contacts(self, contacts, rows, impulse, state) -> None:
        """One island's sub-step into the tally: per contact its impulse on B (λₙ n + λ₁ t₁ + λ₂ t₂: the rows'
        directions), per body the impulse and its angular impulse about the COM (A gets the opposite)."""
        tally = self._tally
        m = contacts.count
        from ..solver.sequential_impulse import tangent_basis_scalar

        tangents = np.array([tangent_basis_scalar(*contacts.normal[c]) for c in range(m)]).reshape(m, 2, 3)
        friction = impulse[:, 1, None] * tangents[:, 0] + impulse[:, 2, None] * tangents[:, 1]
        on_b = impulse[:, 0, None] * contacts.normal + friction
        for side, sign in ((contacts.body_a, -1.0), (contacts.body_b, 1.0)):
            hit = np.flatnonzero(side >= 0)
            if hit.size:
                body = side[hit]
                force = sign * on_b[hit]
                np.add.at(tally["body_impulse"], (body, slice(0, 3)), force)
                np.add.at(tally["body_impulse"], (body, slice(3, 6)),
                          np.cross(contacts.point[hit] - state.position[body], force))
                touched = (contacts.separation[hit] <= 0.0) | (impulse[hit, 0] > 0.0)
                tally["touched"][body[touched]] = True
        tally["steps"].append((self._substeps, contacts.key.copy(), contacts.body_a.copy(), contacts.body_b.copy(),
                               contacts.point.copy(), contacts.normal.copy(), contacts.separation.copy(),
                               impulse[:, 0].copy(), friction))

    def finish_report(self, report, dt: float):
        """``report`` (the body solver's :class:`~cgp_core.solver.report.ContactReport` of the tick) with the
        robot stage's contacts added: the contacts of the last sub-step with their impulses summed over the
        sub-steps they persisted in (matched by key), and every body's contact force and torque."""
        from ..solver.report import ContactReport

        tally, self._tally = self._tally, None
        if tally is None:
            return report
        steps = tally["steps"]
        last = max((s[0] for s in steps), default=None)
        fields = [np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0),
                  np.zeros(0), np.zeros((0, 3))]
        if last is not None:
            final = [s for s in steps if s[0] == last]
            key = np.concatenate([s[1] for s in final])
            normal_impulse = np.concatenate([s[7] for s in final])
            friction = np.concatenate([s[8] for s in final])
            for s in steps:
                if s[0] == last:
                    continue
                for c, k in enumerate(s[1]):
                    hit = np.flatnonzero(key == k)
                    if hit.size:
                        normal_impulse[hit[0]] += s[7][c]
                        friction[hit[0]] += s[8][c]
            separation = np.concatenate([s[6] for s in final])
            pick = (separation <= 0.0) | (normal_impulse > 0.0)
            fields = [np.concatenate([s[2] for s in final]).astype(np.intp)[pick],
                      np.concatenate([s[3] for s in final]).astype(np.intp)[pick],
                      np.concatenate([s[4] for s in final])[pick], np.concatenate([s[5] for s in final])[pick],
                      separation[pick], normal_impulse[pick], friction[pick]]
        n = len(tally["touched"])
        wrench = np.zeros((n, 6))
        listed = tally["touched"].copy()
        inside = report.body < n
        listed[report.body[inside]] = True
        wrench[report.body[inside], :3] = report.force[inside]
        wrench[report.body[inside], 3:] = report.torque[inside]
        wrench[tally["touched"]] += tally["body_impulse"][tally["touched"]] / dt
        body = np.flatnonzero(listed)
        contacts = [np.concatenate((old, new)) for old, new in zip(report[:7], fields)]
        return ContactReport(*contacts, body, wrench[body, :3], wrench[body, 3:], report.duration)

    def integrate(self, h: float) -> None:
        """q ← q + h q̇ per robot (a floating root's quaternion by the exponential map); the bodies' poses and
        velocities there are kept for :meth:`write_bodies` (one compiled call for all robots:
        :func:`~cgp_core.robots.algorithms.advance_all`)."""
        moving = self.qd + self._pseudo  # the position stage's pseudo-velocity moves q, never qd (no energy)
        if self._smooth:  # a Gauss–Legendre step's own displacement (joint_integrators; 0 for the other robots):
            # D − ½ (qd_c + qd⁺), the rows' and drives' velocity change Δ = qd⁺ − qd_c moving q by h Δ / 2; taken
            # here, not at the end of solve, since a robot coupled to free bodies gets its qd⁺ in the body
            # solver's loop (coupled.py), after solve
            moving += np.where(self._stepped, self._flow_displacement - 0.5 * (self._collocated + self.qd), 0.0)
        B = self._body_start[-1]
        rotation, position = np.empty((B, 3, 3)), np.empty((B, 3))
        linear, angular = np.empty((B, 3)), np.empty((B, 3))
        if self.robots:
            algorithms.advance_all(self._models, tuple(self._starts), self.q, moving, self.qd, h,
                                   (rotation, position, linear, angular))
        self._poses = _Poses(rotation, position, self._body_start)
        self._velocities = (rotation, position, linear, angular)
        if self._looped:
            self._project_loops()
            self._velocities = None  # q moved: write_bodies computes the kinematics again

    def _project_loops(self, iterations: int = 4, tolerance: float = 1e-13) -> None:
        """Each articulation's loop closures made exact again after the integration (a Newton projection of q
        onto C(q) = 0, mass-weighted: Δq = −M⁻¹ Jᵀ (J M⁻¹ Jᵀ)⁺ C): the velocity rows keep J qd = 0 and the
        position stage corrects the error at the sub-step's start, but a step along the tangent leaves the
        curvature's ½ (h ω)² r; this removes it.  Velocities are not touched (no energy is added)."""
        for k in self._looped:
            if self._sleeping[k]:
                continue  # asleep: q kept as it is
            r = self.robots[k]
            q = self.q[r.q_slice]
            for _ in range(iterations):
                rotation, position = algorithms.forward_kinematics(r.kernel_arrays, q)
                rows = [loop.rows(r.arrays, rotation, position) for loop in r.spec.articulation.loops]
                J = np.vstack([j for j, _ in rows])
                C = np.concatenate([c for _, c in rows])
                if np.abs(C).max() <= tolerance:
                    break
                W = np.linalg.solve(algorithms.mass_matrix(r.kernel_arrays, q), J.T)
                dq = -W @ (np.linalg.pinv(J @ W, rcond=1e-10) @ C)
                q = algorithms.integrate_positions(r.kernel_arrays, q, dq, 1.0)
            self.q[r.q_slice] = q

    def write_bodies(self, body_model, state) -> None:
        """Every moving link body's pose (COM, orientation) and momenta (P = m v, L = I_world ω) from q, q̇ (the
        kinematics per robot — from :meth:`integrate` when it just ran —, the rest for all robots' links at
        once)."""
        flat, self._velocities = getattr(self, "_velocities", None), None
        rows = self._all_rows
        if flat is None:  # not right after integrate: the kinematics at the current q
            self.prepare()
            rotation, position = self._poses.rotation, self._poses.position
            velocities = [algorithms.body_velocities(r.kernel_arrays, self.q[r.q_slice], self.qd[r.dof_slice],
                                                     *self._poses[k]) for k, r in enumerate(self.robots)]
            linear = np.concatenate([v[0] for v in velocities]) if self.robots else np.zeros((0, 3))
            angular = np.concatenate([v[1] for v in velocities]) if self.robots else np.zeros((0, 3))
        else:
            rotation, position, linear, angular = flat
        if not rows.size:
            return
        algorithms.write_link_bodies(rows, self._all_link_index, (rotation, position, linear, angular),
                                     (self._all_com, self._all_mass_flat, self._all_inertia),
                                     (state.position, state.orientation,
                                      state.rotation if state.rotation is not None else _NO_ROTATION,
                                      state.linear_momentum, state.angular_momentum))

    def contain_blowups(self, body_model, state) -> list[str]:
        """Put back every robot whose state went non-finite or absurd (a link faster than
        :data:`~cgp_core.limits.BLOWUP_SPEED` or spinning faster than :data:`~cgp_core.limits.BLOWUP_SPIN`):
        its initial positions at rest, its drives holding them, its solver's warm start forgotten; the others go
        on.  Returns the names of the robots put back (the World reports them as events)."""
        from ..limits import BLOWUP_SPEED, BLOWUP_SPIN
        from .joint_solver import JointSolverMemory

        def per_robot(flags, starts):  # how many of the flags (along q or qd) are set in each robot's part
            counts = np.concatenate(([0], np.cumsum(flags)))
            return counts[starts[1:]] - counts[starts[:-1]]

        if np.isfinite(self.q).all() and np.isfinite(self.qd).all():  # the usual case: no count needed
            broken = np.zeros(len(self.robots), bool)
        else:
            broken = (per_robot(~np.isfinite(self.q), self._starts.q)
                      + per_robot(~np.isfinite(self.qd), self._starts.dof)) > 0
        rows = getattr(self, "_all_rows", np.zeros(0, np.int64))
        if rows.size:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                # every body's speed and spin once (the world's I⁻¹ at its poses: once per tick, not once per robot)
                speed = np.linalg.norm(state.linear_momentum, axis=1) / body_model.mass
                spin = np.linalg.norm(state.angular_velocity(body_model), axis=1)
                absurd = ~((speed < BLOWUP_SPEED) & (spin < BLOWUP_SPIN))
            broken[self.body_robot[rows[absurd[rows]]]] = True
        bad = np.flatnonzero(broken).tolist()
        if not bad:
            return []
        initial = self._initial_drives()
        for k in bad:
            r = self.robots[k]
            self.q[r.q_slice] = self.q0[r.q_slice]
            self.qd[r.dof_slice] = 0.0
            self._pseudo[r.dof_slice] = 0.0
            for field, start in zip(self.drives, initial):
                field[r.dof_slice] = start[r.dof_slice]
            if r.solver is not None:
                r.solver.reset()
            self._set_memory(k, JointSolverMemory.empty())
        self.write_bodies(body_model, state)
        return [self.robots[k].name for k in bad]

    def end_tick(self) -> None:
        """The tick's mean joint efforts (what a joint torque sensor would read over the tick)."""
        if self._substeps:
            effort = self._effort_sum / self._substeps
            for k in np.flatnonzero(self._sleeping):  # asleep: what its joints last held (a sensor's reading)
                effort[self.robots[k].dof_slice] = self.effort[self.robots[k].dof_slice]
            self.effort = effort
        self._effort_sum[:] = 0.0
        self._substeps = 0

    # ---- queries and commands -------------------------------------------------------------------------------

    def joint_positions(self, name: str) -> dict[str, float]:
        """The movable joints' positions of robot ``name``, by joint name (URDF order)."""
        r = self.robot(name)
        q = self.q[r.q_slice]
        return {joint: float(q[_q_index(r.model, k)]) for k, joint in enumerate(r.model.dof_names)
                if self._q_of_dof()[r.dof_slice.start + k] >= 0}

    def frame_poses(self, name: str) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
        """Every URDF link frame of robot ``name`` in the world: ``(names, rotation (f, 3, 3), position (f, 3))``."""
        r = self.robot(name)
        k = self.robots.index(r)
        rotation, position = self._poses[k] if hasattr(self, "_poses") else algorithms.forward_kinematics(
            r.kernel_arrays, self.q[r.q_slice])
        m = r.model
        R = rotation[m.frame_body] @ m.frame_rotation
        p = position[m.frame_body] + np.einsum("kij,kj->ki", rotation[m.frame_body], m.frame_position)
        return m.frame_names, R, p

    def visuals(self, name: str) -> tuple:
        """Every ``<visual>`` of robot ``name`` as a :class:`~cgp_core.robots.model.Geometry` (its pose in the
        frame of the robot body it is on), in model order: bodies parent before child, each body's visuals in
        URDF order (a merged link's after its body's own).  Empty for a scene articulation (no URDF)."""
        return tuple(g for per_body in self.robot(name).model.visuals for g in per_body)

    def visual_poses(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Where every visual of robot ``name`` (:meth:`visuals`' order) is in the world now: ``(rotation
        (v, 3, 3), position (v, 3) [m])``, the pose of the body it is on (forward kinematics at the current q)
        composed with the visual's origin: R = R_b R_v, p = p_b + R_b p_v."""
        r = self.robot(name)
        k = self.robots.index(r)
        rotation, position = self._poses[k] if hasattr(self, "_poses") else algorithms.forward_kinematics(
            r.kernel_arrays, self.q[r.q_slice])
        m = r.model
        if m.__dict__.get("_visual_frames") is None:  # (v,) body, (v, 3, 3) and (v, 3) origin: made once
            body = np.array([b for b, per_body in enumerate(m.visuals) for _ in per_body], np.int64)
            local_R = np.array([g.rotation for g in self.visuals(name)], float).reshape(len(body), 3, 3)
            local_p = np.array([g.position for g in self.visuals(name)], float).reshape(len(body), 3)
            object.__setattr__(m, "_visual_frames", (body, local_R, local_p))
        body, local_R, local_p = m.__dict__["_visual_frames"]
        R_b, p_b = rotation[body], position[body]
        return R_b @ local_R, p_b + np.einsum("kij,kj->ki", R_b, local_p)

    # ---- the facade the node uses (cgp_sim_ros: joint_states, joint_commands, robot_description, TF) ---------

    def description(self, name: str) -> str:
        """The URDF XML of robot ``name`` as loaded (xacro expanded): what ``robot_description`` publishes."""
        return self.robot(name).model.source

    def _movable(self, r: RobotInstance) -> list[tuple[str, int]]:
        """``(joint name, world dof index)`` of a robot's 1-dof joints, in URDF order."""
        q_of = self._q_of_dof()
        return [(joint, r.dof_slice.start + k) for k, joint in enumerate(r.model.dof_names)
                if q_of[r.dof_slice.start + k] >= 0]

    def joint_state(self, name: str) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray]:
        """``(names, position (k,), velocity (k,), effort (k,))`` of robot ``name``'s movable 1-dof joints in URDF
        order (mimic followers included), SI units; effort: the mean over the last tick (:attr:`effort`)."""
        r = self.robot(name)
        movable = self._movable(r)
        dofs = np.array([d for _, d in movable], np.int64)
        q_of = self._q_of_dof()
        return (tuple(j for j, _ in movable), self.q[q_of[dofs]].copy(), self.qd[dofs].copy(),
                self.effort[dofs].copy())

    def command(self, name: str, names, position=(), velocity=(), effort=()) -> list[str]:
        """Drive targets from a ``sensor_msgs/JointState`` command, as topic_based_ros2_control sends them: per
        joint ``names[i]``, the first of ``position[i]``, ``velocity[i]``, ``effort[i]`` that exists chooses the
        drive (position: the implicit position drive with the robot's gains; velocity: a velocity drive with its
        damping gain; effort: a joint torque / force).  A command holds until the next one for that joint.

        What is valid is applied; the rest is returned as rejections, one string each naming the joint and the
        reason (unknown joint, a mimic follower, a non-finite value); a target beyond the URDF's limits is
        clamped to them and said so."""
        from .joint_solver import DRIVE_EFFORT, DRIVE_POSITION, DRIVE_VELOCITY

        r = self.robot(name)
        self._commanded.add(self.robots.index(r))  # a command wakes the robot (World.step)
        movable = dict(self._movable(r))
        followers = set(self._mimic[0].tolist())
        problems = []
        names = list(names)
        for label, values in (("position", position), ("velocity", velocity), ("effort", effort)):
            if len(values) > len(names):
                problems.append(f"{name}: {label} has {len(values)} entries for {len(names)} names: ignored")
                return problems
        if len(set(names)) != len(names):
            problems.append(f"{name}: a joint is named twice in one command: ignored")
            return problems
        d = self.drives
        for i, joint in enumerate(names):
            dof = movable.get(joint)
            if dof is None:
                problems.append(f"{name}: no movable joint {joint!r} (joints: {', '.join(movable)})")
                continue
            if dof in followers:
                leader = int(self._mimic[1][list(self._mimic[0]).index(dof)])
                problems.append(f"{name}: joint {joint} mimics {self._dof_name(leader)}: command that one")
                continue
            lo, hi = self._joint_limits["lower"][dof], self._joint_limits["upper"][dof]
            if i < len(position):
                value = float(position[i])
                if not np.isfinite(value):
                    problems.append(f"{name}: joint {joint}: position {value} is not finite")
                    continue
                if not lo <= value <= hi:
                    problems.append(f"{name}: joint {joint}: position {value:g} clamped to its limits [{lo:g}, {hi:g}]")
                    value = min(max(value, lo), hi)
                d.mode[dof], d.target_position[dof], d.target_velocity[dof] = DRIVE_POSITION, value, 0.0
                d.stiffness[dof], d.damping[dof] = self._gains(dof)
            elif i < len(velocity):
                value = float(velocity[i])
                limit = self._joint_limits["velocity_limit"][dof]
                if not np.isfinite(value):
                    problems.append(f"{name}: joint {joint}: velocity {value} is not finite")
                    continue
                if abs(value) > limit:
                    problems.append(f"{name}: joint {joint}: velocity {value:g} clamped to its limit ±{limit:g}")
                    value = float(np.clip(value, -limit, limit))
                d.mode[dof], d.target_velocity[dof] = DRIVE_VELOCITY, value
                d.stiffness[dof], d.damping[dof] = 0.0, self._gains(dof)[1]
            elif i < len(effort):
                value = float(effort[i])
                limit = self._joint_limits["effort_limit"][dof]
                if not np.isfinite(value):
                    problems.append(f"{name}: joint {joint}: effort {value} is not finite")
                    continue
                if abs(value) > limit:
                    problems.append(f"{name}: joint {joint}: effort {value:g} clamped to its limit ±{limit:g}")
                    value = float(np.clip(value, -limit, limit))
                d.mode[dof], d.target_effort[dof] = DRIVE_EFFORT, value
                d.stiffness[dof] = d.damping[dof] = 0.0
        return problems

    def _gains(self, dof: int) -> tuple[float, float]:
        for r in self.robots:
            if r.dof_slice.start <= dof < r.dof_slice.stop:
                return r.spec.stiffness, r.spec.damping
        raise IndexError(dof)

    def _dof_name(self, dof: int) -> str:
        for r in self.robots:
            if r.dof_slice.start <= dof < r.dof_slice.stop:
                return r.model.dof_names[dof - r.dof_slice.start]
        raise IndexError(dof)

    def transforms(self, name: str) -> list[tuple[str, str, np.ndarray, np.ndarray, bool]]:
        """TF of robot ``name``: ``(parent, child, quaternion (4,) xyzw, translation (3,) [m], static)`` for every
        URDF link — the root link in ``world``; the link heading each moving body in the link heading its parent
        body (the joint's transform at the current q); a link merged into a body (a fixed joint) in the link
        heading that body, static.  Every link is reached, as RViz's RobotModel and Foxglove's URDF layer need.
        (robot_state_publisher hangs a child on its URDF parent link; the two differ only below a link that is
        itself merged into its parent, and give the same poses.)"""
        r = self.robot(name)
        k = self.robots.index(r)
        m = r.model
        rotation, position = self._poses[k]
        fixed_root = int(m.joint_type[0]) == JOINT_FIXED_ROOT
        parents, children, rotations, translations, static = [], [], [], [], []
        for b in range(m.n_bodies):
            p = int(m.parent[b])
            if p < 0:
                R, t, parent, fixed = rotation[b], position[b], "world", fixed_root
            else:
                R = rotation[p].T @ rotation[b]
                t = rotation[p].T @ (position[b] - position[p])
                parent, fixed = m.body_names[p], False
            parents.append(parent)
            children.append(m.body_names[b])
            rotations.append(R)
            translations.append(np.array(t, float))
            static.append(fixed)
        heads = set(m.body_names)
        for f, frame in enumerate(m.frame_names):
            if frame in heads:
                continue
            b = int(m.frame_body[f])
            parents.append(m.body_names[b])
            children.append(frame)
            rotations.append(m.frame_rotation[f])
            translations.append(np.asarray(m.frame_position[f], float).copy())
            static.append(True)
        quaternions = matrix_to_quat(np.array(rotations))  # one batched call: ~130 µs each one by one
        return list(zip(parents, children, quaternions, translations, static))


class CoupledRobots:
    """The robots whose links touch free bodies in this sub-step, prepared by :meth:`Robots.solve` as one
    :class:`Island` for the body solver's loop: the body solver calls :meth:`solve` where it would call its own
    kernel (``SequentialImpulseSolver.solve_velocities(..., coupled=...)``), and the robot rows and the body rows
    are solved together (:func:`cgp_core.robots.coupled.step_coupled`); the robots' results are written back here,
    the body solver's returned."""

    def __init__(self, robots: Robots, island: Island, state):
        self._robots, self._island, self._state = robots, island, state

    def solve(self, contacts, bodies, memory, settings, tally, report, profile):
        """:func:`~cgp_core.solver.sequential_impulse.solve_step`'s arguments and result, with the robots' rows in
        the same loop."""
        from .coupled import step_coupled
        from .joint_solver import STAGES, JointSolverMemory, JointStep

        island, robots = self._island, self._robots
        seconds = np.zeros(len(STAGES))
        joint_problem = (tuple(island.system), tuple(island.properties), tuple(island.drives), tuple(island.rows),
                         tuple(island.memory), robots._settings)
        (step, memory_after), body = step_coupled(joint_problem, (contacts, bodies, memory, settings, tally, report),
                                                  seconds, profile)
        step = JointStep(*step)
        robots._island_solved(island, step, JointSolverMemory(*memory_after), seconds, self._state)
        robots._body_displacement = step.body_displacement
        robots.coupled = None  # solved: nothing of this sub-step is kept past it (a copy of the world copies none)
        return body

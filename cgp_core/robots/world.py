"""Robots in a :class:`~cgp_core.world.World`: the robot stage of each rigid-body sub-step.

The world's robots are one system in **reduced coordinates**: the joint positions ``q`` and velocities ``qd`` of
every robot side by side (robot ``r``'s at ``q_offset[r]`` / ``dof_offset[r]``), with the block-diagonal mass
matrix of their trees (:func:`~cgp_core.robots.algorithms.mass_matrix`, the composite-rigid-body algorithm) and
their bias forces (:func:`~cgp_core.robots.algorithms.inverse_dynamics` with q̈ = 0: Coriolis, centrifugal,
gravity).  Joints are exact by construction: a link's pose is a function of q, so no joint can stretch, whatever
the mass ratios.  Everything that constrains the joint velocities is a row of
:mod:`cgp_core.robots.joint_solver`: joint limits, drives bounded by the effort limit, mimic couplings, joint
friction, and the **contacts of the links** — with the ground, fixed bodies, free bodies and other links.

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
   solver finds q̇ for the end of the sub-step; the remaining contacts go on to the body solver;
4. solve contacts between free bodies (the body solver, unchanged), integrate bodies; integrate q
   (:func:`~cgp_core.robots.algorithms.integrate_positions`);
5. write the link bodies' poses and momenta from q, q̇.

A contact between a link and a free body is solved in the robot stage only, before the body stage solves the
free bodies' own contacts: the two are one Gauss–Seidel pass over two blocks of rows per sub-step (the free
body's velocity after the robot stage is where the body stage starts).  Bullet's btMultiBody solves all rows in
one loop; a link pushing a box that rests on another box converges over the sub-steps here instead.  (Issue 35
asks for one solve loop; this is the step before it, see docs/robots.md.)
"""

from __future__ import annotations

import numpy as np

from ..rotation import matrix_to_quat, quat_to_matrix
from ..scene.robots import RobotSpec
from . import algorithms
from .links import link_body_specs, link_name
from .model import JOINT_FIXED_ROOT, JOINT_FLOATING, JOINT_PRISMATIC, JOINT_REVOLUTE, neutral_positions

#: the combined joint space of all robots is solved densely (a Cholesky factor of the whole block-diagonal
#: matrix): beyond this many joint velocities in one world the cost would grow as dofs³
MAX_WORLD_DOFS = 256


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
        self.q_slice = slice(q_offset, q_offset + self.model.n_q)
        self.dof_slice = slice(dof_offset, dof_offset + self.model.n_dofs)

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


def _q_index(model, dof: int) -> int:
    """The position index of a 1-dof joint's velocity index ``dof``."""
    body = int(np.searchsorted(model.dof_start, dof, side="right") - 1)
    return int(model.q_start[body] + (dof - model.dof_start[body]))


class Robots:
    """All robots of a world and their combined joint-space state (see the module docstring).

    Attributes (arrays of the world's combined joint space):
        q:          (n_q,) joint positions [rad, m; a floating root: position + quaternion xyzw].
        qd:         (n_dofs,) joint velocities [rad/s, m/s; a floating root: world-frame v, ω].
        effort:     (n_dofs,) the joint efforts [N m, N] applied in the last tick, averaged over its sub-steps.
        drives:     the joint solver's drive targets and gains (:class:`~cgp_core.robots.joint_solver.JointDrives`).
        body_robot, body_link: (n_bodies,) int64 per world body: the robot and the robot body it is, −1 for a
                    body that is not a moving link (set by :meth:`attach`).
    """

    def __init__(self, specs: list[RobotSpec]):
        self.robots: list[RobotInstance] = []
        q_offset = dof_offset = 0
        for spec in specs:
            robot = RobotInstance(spec, q_offset, dof_offset)
            self.robots.append(robot)
            q_offset += robot.model.n_q
            dof_offset += robot.model.n_dofs
        if dof_offset > MAX_WORLD_DOFS:
            raise ValueError(f"the robots have {dof_offset} joint velocities in all; a world holds at most "
                             f"{MAX_WORLD_DOFS}")
        self.n_q, self.n_dofs = q_offset, dof_offset
        self.q0 = np.concatenate([r.initial_positions() for r in self.robots]) if self.robots else np.zeros(0)
        self.qd0 = np.zeros(self.n_dofs)
        for r in self.robots:  # a scene's jointed bodies start with their scene velocities (articulations)
            if r.spec.articulation is not None:
                self.qd0[r.dof_slice] = r.spec.articulation.velocity
        self._joint_limits = self._per_dof("lower", "upper", "effort_limit", "velocity_limit", "damping",
                                           "friction")
        self._mimic = self._mimic_rows()
        from .joint_solver import JointProperties

        lim = self._joint_limits
        self._properties = JointProperties(lim["lower"], lim["upper"], lim["effort_limit"], lim["velocity_limit"],
                                           lim["damping"], lim["friction"], *self._mimic,
                                           np.zeros((0, self.n_dofs)), np.zeros(0))
        self._solver = None
        self.body_robot = np.zeros(0, np.int64)
        self.body_link = np.zeros(0, np.int64)
        self.reset()

    # ---- robots added and removed at run time (World.spawn / World.delete) ------------------------------------

    def with_robot(self, spec: RobotSpec) -> Robots:
        """A new :class:`Robots` with ``spec``'s robot appended (its coordinates last in the combined joint space,
        at its initial positions, at rest, its drives holding them if ``hold``); every robot already here keeps
        its joint positions, velocities, efforts, drives (commands included) and pending wrench torques.  The
        joint solver starts cold (its warm start is per contact point of the old joint space).  ValueError past
        MAX_WORLD_DOFS; call :meth:`attach` with the new body model."""
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
            rotation, position = algorithms.forward_kinematics(r.arrays, self.q0[r.q_slice])
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
                row = index.get(link if r.spec.articulation is not None else link_name(r.name, link))
                if row is None:
                    continue
                self.self_collision_group[row] = k
                if not body_model.fixed[row]:
                    self.body_robot[row], self.body_link[row] = k, b

    def reset(self) -> None:
        self.q = self.q0.copy()
        self.qd = self.qd0.copy()
        self.effort = np.zeros(self.n_dofs)
        self._effort_sum = np.zeros(self.n_dofs)
        self._substeps = 0
        if self._solver is not None:
            self._solver.reset()
        self.drives = self._initial_drives()
        self._wrench_torque = np.zeros(self.n_dofs)
        self._pseudo = np.zeros(self.n_dofs)
        self.prepare()

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
        rows = np.flatnonzero(self.body_robot >= 0)
        if not rows.size:
            return
        F, T = state.force[rows], state.torque[rows]
        loaded = np.flatnonzero((F != 0.0).any(axis=1) | (T != 0.0).any(axis=1))
        for i in loaded:
            row = rows[i]
            r = self.robots[self.body_robot[row]]
            link = int(self.body_link[row])
            rotation, position = self._poses[self.body_robot[row]]
            com = state.position[row]
            Jp = algorithms.point_jacobian(r.arrays, rotation, position, link, com)
            Jw = algorithms.angular_jacobian(r.arrays, rotation, position, link)
            self._wrench_torque[r.dof_slice] += Jp.T @ F[i] + Jw.T @ T[i]
        state.force[rows] = 0.0
        state.torque[rows] = 0.0

    def prepare(self) -> None:
        """The body poses of every robot at the current q (cached for the sub-step)."""
        self._poses = [algorithms.forward_kinematics(r.arrays, self.q[r.q_slice]) for r in self.robots]
        self._loop_rows()

    def _loop_rows(self) -> None:
        """The articulations' loop closures at the current q, as the joint solver's equality rows (three per
        loop: :meth:`cgp_core.robots.articulations.LoopClosure.rows`)."""
        blocks, errors = [], []
        for k, r in enumerate(self.robots):
            if r.spec.articulation is None:
                continue
            rotation, position = self._poses[k]
            for loop in r.spec.articulation.loops:
                J, C = loop.rows(r.arrays, rotation, position)
                block = np.zeros((3, self.n_dofs))
                block[:, r.dof_slice] = J
                blocks.append(block)
                errors.append(C)
        if blocks:
            self._properties = self._properties._replace(equality_jacobian=np.vstack(blocks),
                                                         equality_error=np.concatenate(errors))

    def loop_errors(self) -> dict[str, float]:
        """Every loop-closing joint's error |p_a − p_b| [m] at the current q, by joint name."""
        out = {}
        for r in self.robots:
            if r.spec.articulation is None:
                continue
            rotation, position = algorithms.forward_kinematics(r.arrays, self.q[r.q_slice])
            for loop in r.spec.articulation.loops:
                pa, pb = loop.points(rotation, position)
                out[loop.name] = float(np.linalg.norm(pa - pb))
        return out

    def solve(self, contacts, body_model, state, h: float, gravity, velocity, angular_velocity, inv_inertia):
        """The robot stage (module docstring, step 3): returns the contacts left for the body solver."""
        from .joint_solver import FreeBodies, JointSystem

        if contacts.count:
            a, b = contacts.body_a, contacts.body_b
            link_side_a = (a >= 0) & (self.body_robot[np.maximum(a, 0)] >= 0)
            link_side_b = self.body_robot[b] >= 0
        else:
            link_side_a = link_side_b = np.zeros(0, bool)
        ours = link_side_a | link_side_b
        keep = self._contact_filter(contacts, link_side_a, link_side_b) if ours.any() else np.ones(contacts.count,
                                                                                                     bool)
        ours &= keep
        rest = ~ours & keep
        M = np.zeros((self.n_dofs, self.n_dofs))
        bias = np.zeros(self.n_dofs)
        for r in self.robots:
            q, qd = self.q[r.q_slice], self.qd[r.dof_slice]
            M[r.dof_slice, r.dof_slice] = algorithms.mass_matrix(r.arrays, q)
            bias[r.dof_slice] = algorithms.inverse_dynamics(r.arrays, q, qd, np.zeros(r.model.n_dofs),
                                                            np.asarray(gravity, float))
        q_of = self._q_of_dof()
        coordinate = np.where(q_of >= 0, self.q[np.maximum(q_of, 0)], 0.0)
        system = JointSystem(M, bias, self._wrench_torque.copy(), coordinate, self.qd.copy())
        chosen = np.flatnonzero(ours)
        rows = self._contact_rows(contacts.select(chosen), body_model, state)
        bodies = FreeBodies(np.ascontiguousarray(body_model.inv_mass, dtype=float), inv_inertia,
                            np.ascontiguousarray(np.hstack([velocity, angular_velocity])),
                            state.linear_momentum, state.angular_momentum) if rows.key.size else FreeBodies.empty()
        if self._solver is None or self._solver.settings.h != h:
            from .joint_solver import JointSolver

            memory = self._solver.memory if self._solver is not None else None
            self._solver = JointSolver(h)
            if memory is not None:
                self._solver.memory = memory
        step = self._solver.step(system, self._properties, self.drives, rows, bodies)
        self.qd = step.velocity.copy()
        self._pseudo = step.pseudo_velocity.copy()
        self._effort_sum += step.effort
        self._substeps += 1
        return contacts.select(np.flatnonzero(rest))

    def _q_of_dof(self) -> np.ndarray:
        """(n_dofs,) the position index of every 1-dof joint's velocity (−1 for a floating root's)."""
        if not hasattr(self, "_q_of_dof_cache"):
            out = np.full(self.n_dofs, -1, np.int64)
            for r in self.robots:
                m = r.model
                for b in range(len(m.body_names)):
                    if int(m.joint_type[b]) in (JOINT_REVOLUTE, JOINT_PRISMATIC):
                        out[r.dof_slice.start + m.dof_start[b]] = r.q_slice.start + m.q_start[b]
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

    def _contact_rows(self, contacts, body_model, state):
        """Rows in joint space for the contacts that touch a link (module docstring, step 3): per point the three
        directions (n, t₁, t₂) of the contact solver, each pointing from the other side to the robot's side."""
        from ..solver.sequential_impulse import tangent_basis_scalar
        from .joint_solver import ContactRows

        m = contacts.count
        J = np.zeros((m, 3, self.n_dofs))
        body = np.full(m, -1, np.int64)
        body_jacobian = np.zeros((m, 3, 6))
        for c in range(m):
            n = contacts.normal[c]
            t = tangent_basis_scalar(n[0], n[1], n[2])
            D = np.array([n, [t[0], t[1], t[2]], [t[3], t[4], t[5]]])  # (3 directions, 3), from A to B
            p = contacts.point[c]
            robot_sign = 1.0 if self.body_robot[contacts.body_b[c]] >= 0 else -1.0  # d from the other side
            for side, sign in ((int(contacts.body_a[c]), -1.0), (int(contacts.body_b[c]), 1.0)):
                if side < 0:
                    continue
                k = int(self.body_robot[side])
                if k >= 0:
                    r = self.robots[k]
                    rotation, position = self._poses[k]
                    Jp = algorithms.point_jacobian(r.arrays, rotation, position, int(self.body_link[side]), p)
                    J[c, :, r.dof_slice] += (sign * robot_sign) * (D @ Jp)
                elif body_model.inv_mass[side] > 0.0:
                    body[c] = side
                    arm = p - state.position[side]
                    d = robot_sign * D  # from the body to the robot: the body's row is [−d, −r × d]
                    body_jacobian[c, :, :3] = -d
                    body_jacobian[c, :, 3:] = -np.cross(arm, d)
        return ContactRows(J, body, body_jacobian, contacts.separation.copy(), contacts.friction.copy(),
                           contacts.key % (1 << 37))

    def integrate(self, h: float) -> None:
        """q ← q + h q̇ per robot (a floating root's quaternion by the exponential map)."""
        moving = self.qd + self._pseudo  # the position stage's pseudo-velocity moves q, never qd (no energy)
        for r in self.robots:
            self.q[r.q_slice] = algorithms.integrate_positions(r.arrays, self.q[r.q_slice], moving[r.dof_slice], h)
        self._project_loops()

    def _project_loops(self, iterations: int = 4, tolerance: float = 1e-13) -> None:
        """Each articulation's loop closures made exact again after the integration (a Newton projection of q
        onto C(q) = 0, mass-weighted: Δq = −M⁻¹ Jᵀ (J M⁻¹ Jᵀ)⁺ C): the velocity rows keep J qd = 0 and the
        position stage corrects the error at the sub-step's start, but a step along the tangent leaves the
        curvature's ½ (h ω)² r; this removes it.  Velocities are not touched (no energy is added)."""
        for r in self.robots:
            if r.spec.articulation is None or not r.spec.articulation.loops:
                continue
            q = self.q[r.q_slice]
            for _ in range(iterations):
                rotation, position = algorithms.forward_kinematics(r.arrays, q)
                rows = [loop.rows(r.arrays, rotation, position) for loop in r.spec.articulation.loops]
                J = np.vstack([j for j, _ in rows])
                C = np.concatenate([c for _, c in rows])
                if np.abs(C).max() <= tolerance:
                    break
                W = np.linalg.solve(algorithms.mass_matrix(r.arrays, q), J.T)
                dq = -W @ (np.linalg.pinv(J @ W, rcond=1e-10) @ C)
                q = algorithms.integrate_positions(r.arrays, q, dq, 1.0)
            self.q[r.q_slice] = q

    def write_bodies(self, body_model, state) -> None:
        """Every moving link body's pose (COM, orientation) and momenta (P = m v, L = I_world ω) from q, q̇."""
        self.prepare()
        for k, r in enumerate(self.robots):
            rows = np.flatnonzero(self.body_robot == k)
            if not rows.size:
                continue
            links = self.body_link[rows]
            rotation, position = self._poses[k]
            linear, angular = algorithms.body_velocities(r.arrays, self.q[r.q_slice], self.qd[r.dof_slice],
                                                         rotation, position)
            R = rotation[links]
            com = np.einsum("kij,kj->ki", R, r.model.com[links])
            state.position[rows] = position[links] + com
            state.orientation[rows] = matrix_to_quat(R)
            if state.rotation is not None:
                state.rotation[rows] = R
            v = linear[links] + np.cross(angular[links], com)
            state.linear_momentum[rows] = body_model.mass[rows, None] * v
            inertia_world = R @ body_model.inertia_body[rows] @ np.swapaxes(R, 1, 2)
            state.angular_momentum[rows] = np.einsum("kij,kj->ki", inertia_world, angular[links])

    def contain_blowups(self, body_model, state) -> list[str]:
        """Put back every robot whose state went non-finite or absurd (a link faster than
        :data:`~cgp_core.limits.BLOWUP_SPEED` or spinning faster than :data:`~cgp_core.limits.BLOWUP_SPIN`):
        its initial positions at rest, its drives holding them, the solver's warm start forgotten; the others go
        on.  Returns the names of the robots put back (the World reports them as events)."""
        from ..limits import BLOWUP_SPEED, BLOWUP_SPIN

        bad = []
        with np.errstate(over="ignore", invalid="ignore"):
            for k, r in enumerate(self.robots):
                rows = np.flatnonzero(self.body_robot == k)
                finite = np.isfinite(self.q[r.q_slice]).all() and np.isfinite(self.qd[r.dof_slice]).all()
                if finite and rows.size:
                    speed = np.linalg.norm(state.linear_momentum[rows], axis=1) / body_model.mass[rows]
                    spin = np.linalg.norm(state.angular_velocity(body_model)[rows], axis=1)
                    finite = bool((speed < BLOWUP_SPEED).all() and (spin < BLOWUP_SPIN).all())
                if not finite:
                    bad.append(k)
        if not bad:
            return []
        initial = self._initial_drives()
        for k in bad:
            r = self.robots[k]
            self.q[r.q_slice] = self.q0[r.q_slice]
            self.qd[r.dof_slice] = self.qd0[r.dof_slice] * 0.0
            self._pseudo[r.dof_slice] = 0.0
            for field, start in zip(self.drives, initial):
                field[r.dof_slice] = start[r.dof_slice]
        if self._solver is not None:
            self._solver.reset()
        self.write_bodies(body_model, state)
        return [self.robots[k].name for k in bad]

    def end_tick(self) -> None:
        """The tick's mean joint efforts (what a joint torque sensor would read over the tick)."""
        if self._substeps:
            self.effort = self._effort_sum / self._substeps
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
            r.arrays, self.q[r.q_slice])
        m = r.model
        R = rotation[m.frame_body] @ m.frame_rotation
        p = position[m.frame_body] + np.einsum("kij,kj->ki", rotation[m.frame_body], m.frame_position)
        return m.frame_names, R, p

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

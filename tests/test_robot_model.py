"""The recursive algorithms of cgp_core.robots against Pinocchio (the oracle) and closed forms.

Pinocchio's conventions, converted here: a continuous joint has two position coordinates (cos, sin); its joint
order may differ from ours (mapped by joint name); its free flyer's velocity is (v, ω) in the root body's frame
where ours is in the world's, so ``qd_ours = A qd_pin`` with ``A = blockdiag(R, R)`` on the root's dofs (and the
permutation), ``τ_pin = Aᵀ τ_ours``, ``M_pin = Aᵀ M_ours A`` and ``qdd_ours = A qdd_pin + (ω × v, 0)``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np
import pytest

from cgp_core.robots import (
    JOINT_FLOATING,
    JOINT_PLANAR,
    angular_jacobian,
    bias_forces,
    body_velocities,
    forward_dynamics,
    forward_kinematics,
    frame_poses,
    integrate_positions,
    inverse_dynamics,
    load_urdf,
    mass_matrix,
    neutral_positions,
    point_jacobian,
)

pin = pytest.importorskip("pinocchio")

REPO = Path(__file__).resolve().parents[1]
ARM3 = REPO / "msgs_config" / "robots" / "arm3.urdf"
ARM7 = REPO / "msgs_config" / "robots" / "arm7.urdf"  # the `arm` scene's 7-DoF arm (tools/arm7_urdf.py)
PENDULUM = REPO / "msgs_config" / "robots" / "pendulum.urdf"
GRAVITY = np.array([0.0, 0.0, -9.81])


def _erd_share() -> Path:
    """example-robot-data's share directory (its URDFs refer to meshes as package://example-robot-data/...)."""
    share = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share"
    if not (share / "example-robot-data").is_dir():
        pytest.skip("example-robot-data is not installed")
    return share


def _erd(relative: str) -> Path:
    return _erd_share() / "example-robot-data" / "robots" / relative


PANDA = "panda_description/urdf/panda.urdf"
UR5 = "ur_description/urdf/ur5_robot.urdf"
DOUBLE_PENDULUM = "double_pendulum_description/urdf/double_pendulum_continuous.urdf"


class Pair:
    """Our model and Pinocchio's of one URDF, with the conversions between their coordinates."""

    def __init__(self, path: Path, floating: bool = False):
        self.model = load_urdf(path, package_paths=[_erd_share()], fixed_base=not floating)
        self.arrays = self.model.arrays
        self.pin = (pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer()) if floating
                    else pin.buildModelFromUrdf(str(path)))
        self.data = self.pin.createData()
        assert self.pin.nv == self.model.n_dofs
        self.perm = np.zeros((self.model.n_dofs, self.model.n_dofs))  # qd_ours (root in body axes) = perm qd_pin
        self.joints = []  # (pin joint, our body)
        for j in range(1, self.pin.njoints):
            name = self.pin.names[j]
            body = 0 if self.pin.joints[j].shortname() == "JointModelFreeFlyer" else self.model.joint_names.index(name)
            self.joints.append((j, body))
            for k in range(self.pin.joints[j].nv):
                self.perm[self.model.dof_start[body] + k, self.pin.joints[j].idx_v + k] = 1.0

    def random_state(self, rng):
        m = self.model
        q = rng.uniform(-1.5, 1.5, m.n_q)
        for i in range(m.n_bodies):
            if m.joint_type[i] == JOINT_FLOATING:
                quat = rng.normal(size=4)
                q[m.q_start[i] + 3:m.q_start[i] + 7] = quat / np.linalg.norm(quat)
        return q, rng.normal(size=m.n_dofs), rng.normal(size=m.n_dofs)

    def pin_q(self, q):
        qp = pin.neutral(self.pin)
        for j, body in self.joints:
            jm, s = self.pin.joints[j], self.model.q_start[body]
            if jm.nq == 2:  # continuous: (cos, sin)
                qp[jm.idx_q:jm.idx_q + 2] = np.cos(q[s]), np.sin(q[s])
            else:
                qp[jm.idx_q:jm.idx_q + jm.nq] = q[s:s + jm.nq]
        return qp

    def velocity_map(self, q):
        """A with qd_ours = A qd_pin, and the term (Ȧ qd_pin) as a function of qd_ours."""
        T = np.eye(self.model.n_dofs)
        if self.model.joint_type[0] == JOINT_FLOATING:
            R, _ = forward_kinematics(self.arrays, q)
            T[0:3, 0:3] = R[0]
            T[3:6, 3:6] = R[0]
        return T @ self.perm

    def a_dot_qd(self, qd_ours):
        extra = np.zeros(self.model.n_dofs)
        if self.model.joint_type[0] == JOINT_FLOATING:
            extra[0:3] = np.cross(qd_ours[3:6], qd_ours[0:3])
        return extra


def _close(ours, theirs, rtol=1e-9):
    scale = max(1.0, float(np.abs(theirs).max()))
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=rtol * scale)


CASES = [(PANDA, False), (UR5, False), (DOUBLE_PENDULUM, False), ("arm3", False), ("arm3", True), (PANDA, True),
         ("arm7", False)]


def _path(name):
    return {"arm3": ARM3, "arm7": ARM7}.get(name) or _erd(name)


@pytest.mark.parametrize(("robot", "floating"), CASES, ids=[f"{r.split('/')[-1]}-{'floating' if f else 'fixed'}"
                                                            for r, f in CASES])
def test_dynamics_and_kinematics_equal_pinocchios(robot, floating):
    """M(q) (CRBA), RNEA with and without qdd, the bias, forward dynamics, every frame's pose, a point Jacobian and
    the body velocities equal Pinocchio's at random states (Panda's mimic finger: a joint of its own in both)."""
    pair = Pair(_path(robot), floating)
    model, arrays, pm, data = pair.model, pair.arrays, pair.pin, pair.data
    rng = np.random.default_rng(7)
    for _ in range(3):
        q, qd_pin, qdd_pin = pair.random_state(rng)
        qp = pair.pin_q(q)
        A = pair.velocity_map(q)
        qd = A @ qd_pin
        qdd = A @ qdd_pin + pair.a_dot_qd(qd)

        M_pin = pin.crba(pm, data, qp)
        M_pin = np.triu(M_pin) + np.triu(M_pin, 1).T
        M = mass_matrix(arrays, q)
        _close(A.T @ M @ A, M_pin)
        np.testing.assert_allclose(M, M.T, atol=1e-14)

        tau_pin = pin.rnea(pm, data, qp, qd_pin, qdd_pin)
        tau = inverse_dynamics(arrays, q, qd, qdd, GRAVITY)
        _close(A.T @ tau, tau_pin)
        if not floating:
            _close(A.T @ bias_forces(arrays, q, qd, GRAVITY), pin.nonLinearEffects(pm, data, qp, qd_pin))

        qdd_pin_fd = pin.aba(pm, data, qp, qd_pin, tau_pin)
        qdd_fd = forward_dynamics(arrays, q, qd, np.linalg.solve(A.T, tau_pin), GRAVITY)
        _close(qdd_fd, A @ qdd_pin_fd + pair.a_dot_qd(qd), rtol=1e-8)

        pin.forwardKinematics(pm, data, qp, qd_pin)
        pin.updateFramePlacements(pm, data)
        pin.computeJointJacobians(pm, data, qp)
        rotation, position = forward_kinematics(arrays, q)
        frame_r, frame_x = frame_poses(arrays, rotation, position)
        linear, angular = body_velocities(arrays, q, qd, rotation, position)
        for k, name in enumerate(model.frame_names):
            fid = pm.getFrameId(name)
            np.testing.assert_allclose(frame_r[k], data.oMf[fid].rotation, atol=1e-12, err_msg=name)
            np.testing.assert_allclose(frame_x[k], data.oMf[fid].translation, atol=1e-12, err_msg=name)
            body = model.frame_body[k]
            if model.body_names[body] == name:  # a body frame: its velocity
                v = pin.getFrameVelocity(pm, data, fid, pin.LOCAL_WORLD_ALIGNED)
                _close(linear[body], v.linear)
                _close(angular[body], v.angular)
            J_pin = pin.getFrameJacobian(pm, data, fid, pin.LOCAL_WORLD_ALIGNED)
            _close(point_jacobian(arrays, rotation, position, body, frame_x[k]) @ A, J_pin[:3])
            _close(angular_jacobian(arrays, rotation, position, body) @ A, J_pin[3:])


def test_the_point_jacobian_gives_a_points_velocity_by_finite_differences():
    """J qd is the derivative of a world point fixed to the last body, on a planar + floating + revolute tree."""
    model = load_urdf(_planar_urdf(), fixed_base=False)
    arrays = tuple(model.arrays)  # the plain-tuple form of the bundle works too
    assert model.joint_type[1] == JOINT_PLANAR and model.joint_type[0] == JOINT_FLOATING
    rng = np.random.default_rng(3)
    q = rng.normal(size=model.n_q)
    q[3:7] /= np.linalg.norm(q[3:7])
    qd = rng.normal(size=model.n_dofs)
    body = model.n_bodies - 1
    local = np.array([0.1, -0.2, 0.3])

    def point(q):
        R, x = forward_kinematics(arrays, q)
        return x[body] + R[body] @ local

    h = 1e-6
    numeric = (point(integrate_positions(arrays, q, qd, h)) - point(integrate_positions(arrays, q, qd, -h))) / (2*h)
    R, x = forward_kinematics(arrays, q)
    J = point_jacobian(arrays, R, x, body, point(q))
    np.testing.assert_allclose(J @ qd, numeric, atol=1e-8)
    linear, angular = body_velocities(arrays, q, qd, R, x)
    np.testing.assert_allclose(linear[body] + np.cross(angular[body], R[body] @ local), numeric, atol=1e-8)


def _planar_urdf() -> str:
    link = ('<link name="{0}"><inertial><origin xyz="0.1 0.05 0.02" rpy="0.2 0.1 0"/><mass value="{1}"/>'
            '<inertia ixx="0.01" ixy="0.001" ixz="0" iyy="0.02" iyz="0" izz="0.025"/></inertial></link>')
    return f"""<robot name="planar">
      {link.format('base', 1.0)}{link.format('sled', 2.0)}{link.format('arm', 0.5)}
      <joint name="slide" type="planar"><parent link="base"/><child link="sled"/>
        <origin xyz="0 0 0.1" rpy="0.3 0.2 0.1"/><axis xyz="0.2 0.3 0.9"/></joint>
      <joint name="hinge" type="continuous"><parent link="sled"/><child link="arm"/>
        <origin xyz="0.2 0 0"/><axis xyz="1 0 0"/></joint>
    </robot>"""


def test_planar_dynamics_are_consistent():
    """A planar joint (which Pinocchio's URDF reader does not take with an arbitrary axis): M from CRBA equals the
    Jacobian form Σ (m Jvᵀ Jv + Jωᵀ I Jω) over the bodies (on a floating root), RNEA with qdd = M⁻¹(τ − b) gives τ
    back, and (fixed base: q̇ = qd) the bias without gravity is Lagrange's Coriolis term
    b_k = Σ_j Ṁ_kj qd_j − ½ qdᵀ (∂M/∂q_k) qd, by central differences."""
    model = load_urdf(_planar_urdf(), fixed_base=False)
    arrays = model.arrays
    rng = np.random.default_rng(5)
    q = rng.normal(size=model.n_q)
    q[3:7] /= np.linalg.norm(q[3:7])
    R, x = forward_kinematics(arrays, q)
    M = np.zeros((model.n_dofs, model.n_dofs))
    for i in range(model.n_bodies):
        c = x[i] + R[i] @ model.com[i]
        Jv = point_jacobian(arrays, R, x, i, c)
        Jw = angular_jacobian(arrays, R, x, i)
        M += model.mass[i] * Jv.T @ Jv + Jw.T @ (R[i] @ model.inertia[i] @ R[i].T) @ Jw
    _close(mass_matrix(arrays, q), M, rtol=1e-12)
    qd, tau = rng.normal(size=model.n_dofs), rng.normal(size=model.n_dofs)
    qdd = forward_dynamics(arrays, q, qd, tau, GRAVITY)
    _close(inverse_dynamics(arrays, q, qd, qdd, GRAVITY), tau, rtol=1e-10)

    fixed = load_urdf(_planar_urdf()).arrays
    q, qd = rng.normal(size=4), rng.normal(size=4)
    h = 1e-6
    dM = []
    for k in range(4):
        e = np.zeros(4)
        e[k] = h
        dM.append((mass_matrix(fixed, q + e) - mass_matrix(fixed, q - e)) / (2 * h))
    M_dot = sum(dM[k] * qd[k] for k in range(4))
    lagrange = M_dot @ qd - 0.5 * np.array([qd @ dM[k] @ qd for k in range(4)])
    np.testing.assert_allclose(bias_forces(fixed, q, qd, np.zeros(3)), lagrange, atol=1e-8)


def test_external_forces_enter_as_jacobian_transposes():
    """τ(f_ext) = τ(0) − J_cᵀ f − J_ωᵀ τ_c for a force at the COM of a body and a torque on it."""
    model = load_urdf(ARM3, fixed_base=False)
    arrays = model.arrays
    rng = np.random.default_rng(11)
    q = neutral_positions(model) + np.r_[rng.normal(size=3), 0, 0, 0, 0, rng.normal(size=3)]
    q[3:7] = [0.1, -0.2, 0.3, 0.9]
    q[3:7] /= np.linalg.norm(q[3:7])
    qd, qdd = rng.normal(size=model.n_dofs), rng.normal(size=model.n_dofs)
    f_ext = np.zeros((model.n_bodies, 6))
    body = 2
    f_ext[body] = rng.normal(size=6)
    R, x = forward_kinematics(arrays, q)
    c = x[body] + R[body] @ model.com[body]
    expected = (inverse_dynamics(arrays, q, qd, qdd, GRAVITY)
                - point_jacobian(arrays, R, x, body, c).T @ f_ext[body, :3]
                - angular_jacobian(arrays, R, x, body).T @ f_ext[body, 3:])
    _close(inverse_dynamics(arrays, q, qd, qdd, GRAVITY, f_ext), expected, rtol=1e-12)


def _rk4(arrays, q, qd, h, gravity):
    """One RK4 step of (q, qd) with zero joint forces (joint coordinates only: no floating root)."""
    tau = np.zeros(len(qd))

    def f(q, qd):
        return qd, forward_dynamics(arrays, q, qd, tau, gravity)

    k1 = f(q, qd)
    k2 = f(q + 0.5 * h * k1[0], qd + 0.5 * h * k1[1])
    k3 = f(q + 0.5 * h * k2[0], qd + 0.5 * h * k2[1])
    k4 = f(q + h * k3[0], qd + h * k3[1])
    return (q + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]),
            qd + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]))


def test_single_pendulum_period_is_the_elliptic_integral():
    """Released at rest from θ₀ = 2 rad, the pendulum swings to −θ₀ in half its period,
    T = 4 √(I / (m g d)) K(sin²(θ₀/2)) (I about the pivot; scipy's ellipk takes the parameter m = k²)."""
    from scipy.special import ellipk
    model = load_urdf(PENDULUM)
    arrays = model.arrays
    m, d = model.mass[1], np.linalg.norm(model.com[1])
    I_pivot = model.inertia[1][1, 1] + m * d * d
    theta0 = 2.0
    period = 4 * np.sqrt(I_pivot / (m * 9.81 * d)) * ellipk(np.sin(theta0 / 2) ** 2)
    q, qd, t, h = np.array([theta0]), np.zeros(1), 0.0, 1e-3
    while True:
        q_new, qd_new = _rk4(arrays, q, qd, h, GRAVITY)
        if t > 0.1 and qd[0] < 0.0 <= qd_new[0]:  # at rest again, at −θ₀: half a period
            half = t + h * (-qd[0]) / (qd_new[0] - qd[0])
            break
        q, qd, t = q_new, qd_new, t + h
    assert abs(q[0] + theta0) < 1e-4
    assert abs(2 * half - period) < 1e-6 * period, (2 * half, period)


def _energy(model, arrays, q, qd):
    R, x = forward_kinematics(arrays, q)
    coms = x + np.einsum("nij,nj->ni", R, model.com)
    return 0.5 * qd @ mass_matrix(arrays, q) @ qd - model.mass @ coms @ GRAVITY


def test_double_pendulum_conserves_energy():
    """Two seconds of a double pendulum (RK4, a chaotic swing from (1.5, −0.8) rad): with h = 1 ms the energy
    stays within 1e-6 of the kinetic energy's swing, and halving h shrinks the drift by more than 8 (RK4's fourth
    order: the drift is the integrator's, not the dynamics'; a wrong Coriolis or gravity term drifts at O(1))."""
    model = load_urdf(_erd(DOUBLE_PENDULUM), package_paths=[_erd_share()])
    arrays = model.arrays
    drifts = []
    for h in (1e-3, 5e-4):
        q, qd = np.array([1.5, -0.8]), np.zeros(2)
        e0 = _energy(model, arrays, q, qd)
        kinetic_max = 0.0
        for _ in range(round(2.0 / h)):
            q, qd = _rk4(arrays, q, qd, h, GRAVITY)
            kinetic_max = max(kinetic_max, 0.5 * qd @ mass_matrix(arrays, q) @ qd)
        assert kinetic_max > 1.0  # it swung
        drifts.append(abs(_energy(model, arrays, q, qd) - e0) / kinetic_max)
    assert drifts[0] < 1e-6, drifts
    assert drifts[1] < drifts[0] / 8, drifts


def test_floating_root_integrates_by_the_exponential_map():
    """A floating root turning at a constant world ω about a tilted axis for 1 s in 100 steps: the quaternion is
    the rotation by |ω| t (exact for the exponential map), unit, and the position moved by v t."""
    from cgp_core.rotation import quat_from_rotvec, quat_multiply
    model = load_urdf(ARM3, fixed_base=False)
    arrays = model.arrays
    q = neutral_positions(model)
    q[3:7] = [0.0, 0.0, np.sin(0.2), np.cos(0.2)]
    q0 = q.copy()
    qd = np.zeros(model.n_dofs)
    qd[0:3] = [0.1, -0.2, 0.3]
    qd[3:6] = [0.5, -1.0, 2.0]
    for _ in range(100):
        q = integrate_positions(arrays, q, qd, 0.01)
    np.testing.assert_allclose(q[0:3], qd[0:3], atol=1e-14)
    expected = quat_multiply(quat_from_rotvec(qd[3:6]), q0[3:7])
    np.testing.assert_allclose(q[3:7] * np.sign(q[6]), expected * np.sign(expected[3]), atol=1e-12)
    assert abs(np.linalg.norm(q[3:7]) - 1.0) < 1e-15


_PLAIN = """
import json, numpy as np
from cgp_core.robots import load_urdf, mass_matrix, inverse_dynamics, forward_dynamics, point_jacobian, \
    forward_kinematics
m = load_urdf({path!r}, fixed_base=False)
a = m.arrays
rng = np.random.default_rng(1)
q = rng.normal(size=m.n_q); q[3:7] /= np.linalg.norm(q[3:7])
qd, qdd = rng.normal(size=m.n_dofs), rng.normal(size=m.n_dofs)
g = np.array([0.0, 0.0, -9.81])
R, x = forward_kinematics(a, q)
out = dict(M=mass_matrix(a, q).tolist(), tau=inverse_dynamics(a, q, qd, qdd, g).tolist(),
           qdd=forward_dynamics(a, q, qd, qdd, g).tolist(), J=point_jacobian(a, R, x, 3, x[3] + 0.1).tolist())
print(json.dumps(out))
"""


def test_the_same_results_without_numba():
    """The kernels give the same numbers as plain Python (NUMBA_DISABLE_JIT=1), compiled here."""
    results = []
    for disable in ("1", "0"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=disable, PYTHONPATH=str(REPO))
        out = subprocess.run([sys.executable, "-c", _PLAIN.format(path=str(ARM3))], env=env, cwd=REPO,
                             capture_output=True, text=True, timeout=600)
        assert out.returncode == 0, out.stderr
        results.append(json.loads(out.stdout))
    for key in results[0]:
        np.testing.assert_allclose(results[0][key], results[1][key], rtol=1e-13, atol=1e-13, err_msg=key)

"""Joint-space integrators of a robot's or articulation's smooth dynamics (issue 35: energy over long runs).

**What is integrated.**  The *smooth flow* of a tree in reduced coordinates: q̇ = qd, M(q) q̈ = τ − b(q, qd),
with ``b`` Coriolis, centrifugal and gravity (:func:`~cgp_core.robots.algorithms.joint_space_terms`) and τ the
applied joint efforts of the sub-step (wrench commands as Jᵀ F, constant over it).  Drives, URDF viscous damping,
limits, contacts, mimic couplings and loop closures stay the joint solver's, solved as today on the flow's result.

**The methods** (a scene's ``joint_integrator``, :data:`JOINT_INTEGRATORS`):

- ``semi_implicit_euler`` (the default, for speed: one M and b per sub-step): the joint solver's own step,
  qd⁺ = qd + h A⁻¹ (τ − b(q, qd) + drives), q⁺ = q + h qd⁺ — first order, explicit in the Coriolis terms;
- ``gauss_legendre_4``: the 2-stage Gauss–Legendre implicit Runge–Kutta method (collocation at the Gauss points
  ½ ∓ √3/6): order 4, A-stable, symmetric (time-reversible);
- ``gauss_legendre_6``: the 3-stage Gauss–Legendre method (Gauss points ½, ½ ∓ √15/10): order 6, A-stable,
  symmetric.  Why offered beside the 4th-order one: on the chaotic double pendulum of
  ``tests/test_body_joints.py`` at 60 Hz × 4 sub-steps the 2-stage method's energy error is bounded (an h⁴
  oscillation whose mean stays ≤ 6e-8, no drift over 120 s) but reaches 1.0–1.2e-6 of (m₁ + m₂) g ℓ₁ over 60 s,
  above issue 35's 1e-6; the 3-stage one stays within 3.5e-9 for ~1.1× the 2-stage one's cost per tick
  (``benchmarks/bench_robots.py --joint-integrators``).

Both are applied to the first-order system in (q, qd), not in the canonical (q, p = M(q) qd): a Runge–Kutta method
is not invariant under that nonlinear change of variables, so the map is symplectic exactly only where M is
constant (a single pendulum, prismatic chains), and symmetric (time-reversible) always.  Measured on the double
pendulum (a prototype with its closed-form M, b and ∂L/∂q), the (q, qd) and (q, p) forms of the 2-stage method keep
the energy to the same 1.2e-6 and 1.3e-6 over 60 s: the velocity form is kept because it needs nothing beyond
M and b, which the robot stage computes anyway.  (Departure from the lecture slides, ``../shared/seed/``: they
integrate a free rigid body's momenta P, L by explicit Euler; a tree's state here is (q, qd) — see
:mod:`~cgp_core.robots.algorithms` — and its integrator implicit and of higher order.)

**The stage equations**, for s stages with Butcher matrix a (s, s) and weights w (s,), in local coordinates Θ
about the sub-step's start (q = q₀ ⊕ Θ: q₀ + Θ for 1-dof and planar coordinates, exp(Θ_ω) ⊗ quat for a ball or a
floating root's orientation, as :func:`~cgp_core.robots.algorithms.integrate_positions` moves them)::

    V_i = qd₀ + h Σ_j a_ij K_j,   Θ_i = h Σ_j a_ij dexp⁻¹_{Θ_j}(V_j),   K_i = M(q₀ ⊕ Θ_i)⁻¹ (τ − b(q₀ ⊕ Θ_i, V_i))
    qd⁺ = qd₀ + h Σ_i w_i K_i,    q⁺ = q₀ ⊕ h Σ_i w_i dexp⁻¹_{Θ_i}(V_i)

dexp⁻¹_Θ(ω) = ω − ½ Θ × ω + (1 − (θ/2) cot(θ/2)) / θ² Θ × (Θ × ω) on the rotational dofs (Runge–Kutta–Munthe-Kaas:
a rotation's quaternion moves by the exponential map, its angular velocity is not the derivative of Θ), the
identity elsewhere.  They are solved by **fixed-point iteration** from K_i = q̈(q₀, qd₀): each pass evaluates M
and b at every stage (one :func:`joint_space_terms` and one Cholesky solve per stage) until no stage velocity
h K_i changed by more than ``tolerance`` (1e-13) × (1 + max |qd₀|), or until the change stops shrinking within
1e5 × that (the round-off floor of an ill-conditioned M: :data:`ROUND_OFF`); ~6 passes at 1/240 s on the
double pendulum.  Passes that contract slowly (after :data:`NEWTON_AFTER`, each taking off less than 70 %) hand
over to **simplified Newton** (its matrix I − h a ⊗ ∂q̈/∂qd − h² a² ⊗ ∂q̈/∂Θ by forward differences, made once,
LU-factored by our own loops); a step whose stages do not converge within :data:`MAX_ITERATIONS` passes is
**split** into 2, 4, up to :data:`MAX_PIECES` Gauss–Legendre steps of h / m (the same method at a smaller step;
counted in ``Robots.integrator_subdivided``).  Only past that does the sub-step **fall back** to the default
semi-implicit Euler step for that robot, counted per robot (:attr:`Robots.integrator_fallbacks
<cgp_core.robots.world.Robots>`) and reported by the World as a ``warn`` event: never silent.

**How it meets the joint solver** (no change to it).  The flow is stepped first, from (q₀, qd₀), giving qd_c and
q_c = q₀ ⊕ h D.  The joint solver then takes the sub-step as always, with its momentum balance fed the flow's
velocity change as an *equivalent effort* in place of τ, f = b(q₀, qd₀) + M(q₀) (qd_c − qd₀) / h (so that
M qd₀ + h (f − b) = M(q₀) qd_c: with no row and no drive acting it returns qd_c to round-off), and its drives,
damping and rows act on that: every row constrains the final velocity qd⁺, as in the default step.  The position
is q⁺ = q₀ ⊕ h (D + ½ (qd⁺ − qd_c) + pseudo): the flow's own displacement, plus the rows' and drives' velocity change
Δ = qd⁺ − qd_c taken as a constant acceleration over the sub-step (it moves q by h Δ / 2), plus the position
stage's pseudo-velocity.  :meth:`Robots.integrate <cgp_core.robots.world.Robots.integrate>` gets it through one
term added to its moving velocity qd⁺ + pseudo: D − ½ (qd_c + qd⁺).

Why h Δ / 2 and not the default step's h Δ: a drive (or a resting contact) holding a joint against gravity cancels
the flow's fall each sub-step — the flow moves q by ½ h² q̈ and qd by h q̈, the drive takes Δ = −h q̈ — and only with
½ h Δ does the held joint stay where it is (with h Δ it was pushed up by ½ h² q̈ every sub-step; measured on the
7-DoF arm, the equilibrium then sat 5.8e-4 rad off the default's; now 1.3e-7 rad, with a steady residual qd of
9e-6 rad/s: the stages see the arm fall within the sub-step).  The price: a joint meeting its limit at speed v may
pass it by up to ½ h v for one sub-step (the speculative row assumed q moves by h qd⁺), which the position stage
removes without adding energy.  A loop closure keeps its equality rows and the Newton projection after the
integration.  Where rows or drives act the step is first order, like the default.

Why not the reverse order (the default step first, its rows' and drives' impulses then held constant as a force
through the flow; the first design): the rows are then satisfied by the default step's velocity, not by the one
the flow ends with, and where a light chain whips (h ω ~ 0.4) the two differ by far more than round-off — the
`chain` scene blew up after ~13 s, measured.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit import njit
from ..rotation import quat_multiply_scalar, quat_to_rotvec_scalar
from .algorithms import cholesky_solve, integrate_positions, joint_space_terms, robot_view
from .model import JOINT_BALL, JOINT_FLOATING, RobotArrays, RobotStarts

#: the default: the joint solver's semi-implicit Euler step (no smooth pre-step)
DEFAULT_JOINT_INTEGRATOR = "semi_implicit_euler"

_R3, _R15 = math.sqrt(3.0), math.sqrt(15.0)
#: each method's Butcher tableau (a (s, s), weights (s,)); None: the default step.  Gauss–Legendre: Hairer,
#: Lubich & Wanner, *Geometric Numerical Integration* (2006), Table II.1.1 / Hairer & Wanner II, Table 7.4
JOINT_INTEGRATORS = {
    "semi_implicit_euler": None,
    "gauss_legendre_4": (np.array([[0.25, 0.25 - _R3 / 6.0],
                                   [0.25 + _R3 / 6.0, 0.25]]),
                         np.array([0.5, 0.5])),
    "gauss_legendre_6": (np.array([[5.0 / 36.0, 2.0 / 9.0 - _R15 / 15.0, 5.0 / 36.0 - _R15 / 30.0],
                                   [5.0 / 36.0 + _R15 / 24.0, 2.0 / 9.0, 5.0 / 36.0 - _R15 / 24.0],
                                   [5.0 / 36.0 + _R15 / 30.0, 2.0 / 9.0 + _R15 / 15.0, 5.0 / 36.0]]),
                         np.array([5.0 / 18.0, 4.0 / 9.0, 5.0 / 18.0])),
}
#: a stage velocity changing by no more than this × (1 + max |qd₀|) [rad/s or m/s] ends the iterations
TOLERANCE = 1e-13
#: passes (fixed-point, then simplified Newton) at most in one step before it is split in two
MAX_ITERATIONS = 30
#: a sub-step split into at most this many pieces before it falls back to the default step.  Why split: the passes
#: contract by ~h ‖∂q̈/∂(q, qd)‖ ρ(a); where the `chain` scene's light links whip at ~100 rad/s they stall or diverge
#: at h = 1/240 s (one step took 263 passes, another went non-finite) and converge in 10–13 at h / 2 (measured)
MAX_PIECES = 8
#: fixed-point passes before slow ones (each taking off less than 1 − SLOW of the change) switch to simplified Newton
NEWTON_AFTER = 6
SLOW = 0.3
#: a change that stopped shrinking within this × the tolerance is the round-off floor: converged (1e-13 → 1e-8 of
#: the velocities at most)
ROUND_OFF = 1e5


class Collocation(NamedTuple):
    """A Gauss–Legendre method and the numbers its stage iterations take."""

    a: np.ndarray         # (s, s) Butcher matrix
    w: np.ndarray         # (s,) weights
    h: float              # sub-step [s]
    tolerance: float      # see TOLERANCE
    max_iterations: int   # see MAX_ITERATIONS

    @staticmethod
    def named(name: str, h: float) -> Collocation:
        a, w = JOINT_INTEGRATORS[name]
        return Collocation(a.copy(), w.copy(), float(h), TOLERANCE, MAX_ITERATIONS)


class SmoothStep(NamedTuple):
    """One robot's smooth sub-step (``n`` dofs)."""

    velocity: np.ndarray      # (n,) qd_c, the smooth flow's velocity at the sub-step's end
    displacement: np.ndarray  # (n,) D = Σ w_i dexp⁻¹(V_i): the flow's q_c = q₀ ⊕ h D
    equivalent: np.ndarray    # (n,) b(q₀, qd₀) + M(q₀) (qd_c − qd₀) / h: the effort the joint solver takes for τ
    iterations: int           # passes run (fixed-point, then simplified Newton; all pieces')
    converged: bool           # False: the caller keeps the default step
    pieces: int               # steps of h / pieces it took (1: one step of h)


class SmoothState(NamedTuple):
    """Every robot's joint-space arrays side by side (robot ``k``'s at its :class:`RobotStarts`), for
    :func:`smooth_steps`."""

    q: np.ndarray             # (n_q,) positions at the sub-step's start
    start: np.ndarray         # (n_dofs,) velocities at the sub-step's start
    applied: np.ndarray       # (n_dofs,) in: the applied efforts τ; out: a stepped robot's equivalent effort (a
    #                           robot that did not converge keeps its τ: the default step)
    velocity: np.ndarray      # (n_dofs,) out: a stepped robot's qd_c
    displacement: np.ndarray  # (n_dofs,) out: a stepped robot's D
    stepped: np.ndarray       # (n_dofs,) bool, out: the dof's robot took the collocation (False: the default step)
    iterations: np.ndarray    # (robots,) int64, added to: passes
    subdivided: np.ndarray    # (robots,) int64, added to: sub-steps integrated in 2 or more pieces
    fallbacks: np.ndarray     # (robots,) int64, added to: sub-steps that kept the default step


@njit
def local_rates(joint_type, dof_start, theta, v, out):
    """``out`` (n_dofs,) = dexp⁻¹_Θ(v) on the rotational dofs of ball joints and a floating root (the rate of the
    local coordinates Θ when the quaternion moves as exp(Θ) ⊗ quat₀ with angular velocity v), v elsewhere."""
    for d in range(len(v)):
        out[d] = v[d]
    for i in range(len(joint_type)):
        if joint_type[i] == JOINT_FLOATING:
            d = dof_start[i] + 3
        elif joint_type[i] == JOINT_BALL:
            d = dof_start[i]
        else:
            continue
        tx, ty, tz = theta[d], theta[d + 1], theta[d + 2]
        wx, wy, wz = v[d], v[d + 1], v[d + 2]
        angle2 = tx * tx + ty * ty + tz * tz
        if angle2 < 1e-4:  # the series: the closed form cancels (1 − x cot x ≈ x²/3) for small angles
            alpha = 1.0 / 12.0 + angle2 / 720.0 + angle2 * angle2 / 30240.0
        else:
            half = 0.5 * math.sqrt(angle2)
            alpha = (1.0 - half * math.cos(half) / math.sin(half)) / angle2
        cx, cy, cz = ty * wz - tz * wy, tz * wx - tx * wz, tx * wy - ty * wx          # Θ × ω
        ccx, ccy, ccz = ty * cz - tz * cy, tz * cx - tx * cz, tx * cy - ty * cx      # Θ × (Θ × ω)
        out[d] = wx - 0.5 * cx + alpha * ccx
        out[d + 1] = wy - 0.5 * cy + alpha * ccy
        out[d + 2] = wz - 0.5 * cz + alpha * ccz


@njit
def _acceleration(arrays, q, v, tau, gravity):
    """q̈ = M(q)⁻¹ (τ − b(q, v))."""
    M, bias = joint_space_terms(arrays, q, v, gravity)
    return cholesky_solve(M, tau - bias)


@njit
def _stage_velocities(a, h, qd, K, V):
    """V_i = qd₀ + h Σ_j a_ij K_j (in place)."""
    s, n = K.shape
    for i in range(s):
        for d in range(n):
            x = 0.0
            for j in range(s):
                x += a[i, j] * K[j, d]
            V[i, d] = qd[d] + h * x


@njit
def _stage_displacements(arrays, a, h, theta, V, rates):
    """rates_i = dexp⁻¹_{Θ_i}(V_i), then Θ_i = h Σ_j a_ij rates_j (in place)."""
    s, n = V.shape
    arrays = RobotArrays(*arrays)
    for i in range(s):
        local_rates(arrays.joint_type, arrays.dof_start, theta[i], V[i], rates[i])
    for i in range(s):
        for d in range(n):
            x = 0.0
            for j in range(s):
                x += a[i, j] * rates[j, d]
            theta[i, d] = h * x


@njit
def _lu_factor(G):
    """G = P⁻¹ L U with partial pivoting (our own loops, as the joint solver's Cholesky: no LAPACK, so compiled and
    plain-Python runs agree bit for bit): the packed factors and the row order."""
    m = G.shape[0]
    LU = G.copy()
    order = np.arange(m)
    for k in range(m):
        p, big = k, abs(LU[k, k])
        for r in range(k + 1, m):
            if abs(LU[r, k]) > big:
                p, big = r, abs(LU[r, k])
        if p != k:
            for c in range(m):
                LU[k, c], LU[p, c] = LU[p, c], LU[k, c]
            order[k], order[p] = order[p], order[k]
        d = LU[k, k]
        if d == 0.0:
            continue  # singular: the solve gives inf / nan, which ends in a fallback
        for r in range(k + 1, m):
            LU[r, k] /= d
            f = LU[r, k]
            for c in range(k + 1, m):
                LU[r, c] -= f * LU[k, c]
    return LU, order


@njit
def _lu_solve(LU, order, b):
    m = len(b)
    x = np.empty(m)
    for i in range(m):
        x[i] = b[order[i]]
        for k in range(i):
            x[i] -= LU[i, k] * x[k]
    for i in range(m - 1, -1, -1):
        for k in range(i + 1, m):
            x[i] -= LU[i, k] * x[k]
        x[i] /= LU[i, i]
    return x


@njit
def _newton_matrix(arrays, q, a, h, theta, V, tau, gravity):
    """The LU factors of the simplified-Newton matrix G = I − h (a ⊗ J_v) − h² (a² ⊗ J_q) of the stage equations
    K_i = q̈(q₀ ⊕ Θ_i, V_i) in K (s n × s n), with J_v = ∂q̈/∂qd and J_q = ∂q̈/∂Θ by forward differences at the
    stages' mean (2 n + 1 evaluations; dexp⁻¹ taken as the identity in the Jacobian: Newton's step is still
    exact at its fixed point)."""
    s, n = V.shape
    mean_theta, mean_v = np.zeros(n), np.zeros(n)
    for i in range(s):
        for d in range(n):
            mean_theta[d] += theta[i, d] / s
            mean_v[d] += V[i, d] / s
    base_q = integrate_positions(arrays, q, mean_theta, 1.0)
    f0 = _acceleration(arrays, base_q, mean_v, tau, gravity)
    Jv, Jq = np.empty((n, n)), np.empty((n, n))
    for j in range(n):
        delta = 1.5e-8 * max(1.0, abs(mean_v[j]))
        mean_v[j] += delta
        column = _acceleration(arrays, base_q, mean_v, tau, gravity)
        mean_v[j] -= delta
        for d in range(n):
            Jv[d, j] = (column[d] - f0[d]) / delta
        step = 1.5e-8 * max(1.0, abs(mean_theta[j]))
        mean_theta[j] += step
        column = _acceleration(arrays, integrate_positions(arrays, q, mean_theta, 1.0), mean_v, tau, gravity)
        mean_theta[j] -= step
        for d in range(n):
            Jq[d, j] = (column[d] - f0[d]) / step
    a2 = np.zeros((s, s))
    for i in range(s):
        for j in range(s):
            for k in range(s):
                a2[i, j] += a[i, k] * a[k, j]
    G = np.zeros((s * n, s * n))
    for i in range(s):
        for j in range(s):
            for r in range(n):
                for c in range(n):
                    G[i * n + r, j * n + c] = -h * a[i, j] * Jv[r, c] - h * h * a2[i, j] * Jq[r, c]
    for m in range(s * n):
        G[m, m] += 1.0
    return _lu_factor(G)


@njit
def _displacement_between(arrays, q0, q1, h):
    """The D (n_dofs,) with q₀ ⊕ h D = q₁ (:func:`integrate_positions`' ⊕: a quaternion by the logarithm of
    quat₁ ⊗ quat₀⁻¹, every other coordinate by its difference)."""
    arrays = RobotArrays(*arrays)
    D = np.empty(arrays.n_dofs)
    for i in range(len(arrays.parent)):
        s, d, kind = arrays.q_start[i], arrays.dof_start[i], arrays.joint_type[i]
        if kind == JOINT_FLOATING or kind == JOINT_BALL:
            if kind == JOINT_FLOATING:
                for k in range(3):
                    D[d + k] = (q1[s + k] - q0[s + k]) / h
                s, d = s + 3, d + 3
            x, y, z, w = quat_multiply_scalar(q1[s], q1[s + 1], q1[s + 2], q1[s + 3],
                                              -q0[s], -q0[s + 1], -q0[s + 2], q0[s + 3])
            rx, ry, rz = quat_to_rotvec_scalar(x, y, z, w)
            D[d], D[d + 1], D[d + 2] = rx / h, ry / h, rz / h
        else:
            for k in range(arrays.q_count[i]):
                D[d + k] = (q1[s + k] - q0[s + k]) / h
    return D


@njit
def collocation_step(arrays, q, start, tau, gravity, method):
    """One sub-step of the smooth flow by the Gauss–Legendre method ``method`` (:class:`Collocation`) from (q,
    ``start``) under the applied efforts τ (module docstring): one step of h, or — where its stages do not converge
    (a light chain whipping at ~100 rad/s: h ω ~ 0.4, measured) — 2, 4, … up to :data:`MAX_PIECES` steps of h / m
    in turn, the method unchanged at a smaller step.  Args: ``arrays`` :class:`RobotArrays`, q (n_q,), start and τ
    (n_dofs,), gravity (3,).  Returns the :class:`SmoothStep` (not converged: the caller keeps the default step)."""
    method = Collocation(*method)  # (arrays handed on as the plain tuple: see cgp_core.robots.algorithms)
    n, h = len(start), method.h
    iterations = 0
    pieces = 1
    while pieces <= MAX_PIECES:
        qc, vc = q.copy(), start.copy()
        done = True
        for _ in range(pieces):
            step = _collocate(arrays, qc, vc, tau, gravity, method, h / pieces)
            iterations += step.iterations
            if not step.converged:
                done = False
                break
            if pieces == 1:
                return SmoothStep(step.velocity, step.displacement, step.equivalent, iterations, True, 1)
            qc = integrate_positions(arrays, qc, step.displacement, h / pieces)
            vc = step.velocity
        if done:
            M0, b0 = joint_space_terms(arrays, q, start, gravity)
            equivalent = np.empty(n)
            for r in range(n):
                x = 0.0
                for c in range(n):
                    x += M0[r, c] * (vc[c] - start[c])
                equivalent[r] = b0[r] + x / h
            return SmoothStep(vc, _displacement_between(arrays, q, qc, h), equivalent, iterations, True, pieces)
        pieces *= 2
    return SmoothStep(start.copy(), np.zeros(n), tau.copy(), iterations, False, pieces)


@njit
def _collocate(arrays, q, start, tau, gravity, method, h):
    """One Gauss–Legendre step of ``h`` (module docstring: fixed-point passes, then simplified Newton)."""
    a, w = method.a, method.w
    s, n = len(w), len(start)
    M0, b0 = joint_space_terms(arrays, q, start, gravity)
    first = cholesky_solve(M0, tau - b0)
    K = np.empty((s, n))
    for i in range(s):  # from the acceleration at the start
        for d in range(n):
            K[i, d] = first[d]
    V, theta, rates = np.zeros((s, n)), np.zeros((s, n)), np.zeros((s, n))
    speed = 0.0
    for d in range(n):
        speed = max(speed, abs(start[d]))
    limit = method.tolerance * (1.0 + speed)
    converged = False
    iterations = 0
    previous = math.inf
    newton = False
    LU, order = np.zeros((0, 0)), np.zeros(0, np.int64)
    residual = np.empty(s * n)
    while iterations < method.max_iterations:
        iterations += 1
        _stage_velocities(a, h, start, K, V)
        _stage_displacements(arrays, a, h, theta, V, rates)
        change = 0.0
        for i in range(s):
            k = _acceleration(arrays, integrate_positions(arrays, q, theta[i], 1.0), V[i], tau, gravity)
            for d in range(n):
                if newton:
                    residual[i * n + d] = K[i, d] - k[d]
                else:
                    change = max(change, h * abs(k[d] - K[i, d]))  # (nan: never ≤ limit, so a fallback)
                    K[i, d] = k[d]
        if newton:  # K ← K − G⁻¹ (K − q̈(stages))
            step = _lu_solve(LU, order, residual)
            for i in range(s):
                for d in range(n):
                    change = max(change, h * abs(step[i * n + d]))
                    K[i, d] -= step[i * n + d]
        if change <= limit:
            converged = True
            break
        # at its round-off floor: a change that stopped shrinking (a pass taking off less than half, where the
        # contraction takes off ~95 % a pass) within ROUND_OFF × the tolerance.  Why: an ill-conditioned M cannot
        # resolve 1e-13 of its velocities — the `chain` scene's 30 light links on a heavy ball (cond M ~ 3.5e7)
        # converge in 5 passes to a floor of ~2e-10 rad/s that then wanders (measured), and would otherwise all
        # fall back.  (A change that grows is not taken for divergence: on the chain's fast whips the passes
        # contract unevenly, 0.07 → 0.18 → 0.10 → 0.02 …, and converge by the 18th, measured)
        if change >= 0.5 * previous and change <= ROUND_OFF * limit:
            converged = True
            break
        # fixed-point passes that contract slowly (h ‖∂q̈/∂qd‖ near 1: a light chain whipping after a hard contact
        # took ~0.88 a pass, measured) hand over to simplified Newton, its matrix made once at the stages reached
        if not newton and iterations >= NEWTON_AFTER and change > SLOW * previous:
            _stage_velocities(a, h, start, K, V)
            _stage_displacements(arrays, a, h, theta, V, rates)
            LU, order = _newton_matrix(arrays, q, a, h, theta, V, tau, gravity)
            newton = True
        previous = change
    _stage_velocities(a, h, start, K, V)
    _stage_displacements(arrays, a, h, theta, V, rates)
    velocity, displacement, equivalent = np.empty(n), np.zeros(n), np.empty(n)
    for d in range(n):
        x = 0.0
        for i in range(s):
            x += w[i] * K[i, d]
            displacement[d] += w[i] * rates[i, d]
        velocity[d] = start[d] + h * x
    for r in range(n):  # b₀ + M₀ (qd⁺ − qd₀) / h: the effort the joint solver takes for τ
        x = 0.0
        for c in range(n):
            x += M0[r, c] * (velocity[c] - start[c])
        equivalent[r] = b0[r] + x / h
    for d in range(n):
        if not (math.isfinite(velocity[d]) and math.isfinite(displacement[d]) and math.isfinite(equivalent[d])):
            converged = False
    return SmoothStep(velocity, displacement, equivalent, iterations, converged, 1)


@njit
def smooth_steps(which, models, starts, state, gravity, method):
    """:func:`collocation_step` for the robots ``which`` (int64 indices) in one compiled call, before the joint
    solver; bundles as plain tuples: ``models`` every robot's :class:`RobotArrays` stacked, ``starts`` their
    :class:`RobotStarts`, ``state`` a :class:`SmoothState` (written in place; a robot that did not converge keeps
    its τ, is not marked ``stepped`` and counts a fallback)."""
    starts = RobotStarts(*starts)
    q, start, applied, velocity, displacement, stepped, iterations, subdivided, fallbacks = state
    for t in range(len(which)):
        k = which[t]
        qs, qe, ds, de = starts.q[k], starts.q[k + 1], starts.dof[k], starts.dof[k + 1]
        step = collocation_step(robot_view(models, starts, k), q[qs:qe].copy(), start[ds:de].copy(),
                                applied[ds:de].copy(), gravity, method)
        iterations[k] += step.iterations
        if step.pieces > 1 and step.converged:
            subdivided[k] += 1
        if not step.converged:
            fallbacks[k] += 1
            continue
        for d in range(de - ds):
            applied[ds + d] = step.equivalent[d]
            velocity[ds + d] = step.velocity[d]
            displacement[ds + d] = step.displacement[d]
            stepped[ds + d] = True


__all__ = ["DEFAULT_JOINT_INTEGRATOR", "JOINT_INTEGRATORS", "Collocation", "SmoothState", "SmoothStep",
           "collocation_step", "local_rates", "smooth_steps"]

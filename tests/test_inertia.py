"""Mass properties: the lecture's particle-set inertia against the closed forms, the parallel-axis theorem and
the defining physics L = Σ mᵢ rᵢ × (ω × rᵢ).

The solids are sampled as the lecture builds a body, from point masses: a box by a regular grid of equal
masses, and sphere / cylinder / capsule by cutting the solid into cells of its own curvilinear coordinates
(r, cos θ, φ) or (r, φ, z), each cell's exact mass placed at its coordinate midpoint.  That is the midpoint
rule in every coordinate, so the tensor converges like 1/N² (N cells per coordinate): halving the cells
must divide the error by ~4 (3.5 to 4.5 accepted), and at N = 32 the relative error must be below 2e-3,
i.e. 2/N²: the midpoint-rule error of these smooth integrands is c/N² with c of order one (measured:
c ≈ 0.5–0.9 for the three solids), so 2/N² fails any sampler or closed form that is off by more than that.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cgp_core.bodies import Shape
from cgp_core.inertia import (
    box_inertia,
    capsule_inertia,
    cylinder_inertia,
    parallel_axis,
    particle_mass_properties,
    principal_axes,
    shape_mass_properties,
    solid_sphere_inertia,
)
from cgp_core.rotation import quat_from_rotvec, quat_to_matrix

RNG_SEED = 20240601


# ---- samplers: solids as sets of point masses -------------------------------------------------------------


def _edges(lo: float, hi: float, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    e = np.linspace(lo, hi, n + 1)
    return e[:-1], e[1:], 0.5 * (e[:-1] + e[1:])


def box_grid(size, n: int, mass: float) -> tuple[np.ndarray, np.ndarray]:
    """n³ equal masses at the centres of the cells of an n×n×n grid over the box."""
    axes = [(np.arange(n) + 0.5) / n * s - 0.5 * s for s in size]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return points, np.full(len(points), mass / len(points))


def ball_cells(radius: float, n: int, density: float, u_range=(-1.0, 1.0), centre=(0.0, 0.0, 0.0)):
    """Cells of (r, u = cos θ, φ) over the ball (or a hemisphere by u_range), exact cell masses."""
    r1, r2, rm = _edges(0.0, radius, n)
    u1, u2, um = _edges(u_range[0], u_range[1], n)
    f1, f2, fm = _edges(0.0, 2.0 * math.pi, 2 * n)
    R, U, F = np.meshgrid(rm, um, fm, indexing="ij")
    dr3 = (r2**3 - r1**3) / 3.0
    du, df = u2 - u1, f2 - f1
    masses = density * (dr3[:, None, None] * du[None, :, None] * df[None, None, :])
    s = np.sqrt(1.0 - U * U)
    points = np.stack((R * s * np.cos(F), R * s * np.sin(F), R * U), axis=-1).reshape(-1, 3)
    return points + np.asarray(centre), masses.reshape(-1)


def cylinder_cells(radius: float, half_length: float, n: int, density: float):
    """Cells of (r, φ, z) over the cylinder |z| ≤ half_length, exact cell masses."""
    r1, r2, rm = _edges(0.0, radius, n)
    f1, f2, fm = _edges(0.0, 2.0 * math.pi, 2 * n)
    z1, z2, zm = _edges(-half_length, half_length, n)
    R, F, Z = np.meshgrid(rm, fm, zm, indexing="ij")
    masses = density * (0.5 * (r2**2 - r1**2))[:, None, None] * (f2 - f1)[None, :, None] * (z2 - z1)[None, None, :]
    points = np.stack((R * np.cos(F), R * np.sin(F), Z), axis=-1).reshape(-1, 3)
    return points, masses.reshape(-1)


def capsule_cells(radius: float, half_length: float, n: int, density: float):
    cyl = cylinder_cells(radius, half_length, n, density)
    top = ball_cells(radius, n, density, (0.0, 1.0), (0.0, 0.0, half_length))
    bottom = ball_cells(radius, n, density, (-1.0, 0.0), (0.0, 0.0, -half_length))
    return np.concatenate((cyl[0], top[0], bottom[0])), np.concatenate((cyl[1], top[1], bottom[1]))


def relative_error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# ---- the particle set: the lecture's definitions ---------------------------------------------------------


def lecture_tensor_by_loop(points: np.ndarray, masses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference: COM = Σ mᵢxᵢ / Σ mᵢ and J = Σ Jᵢ with the lecture's matrix (corrected zz entry), one
    particle at a time in plain Python."""
    total = sum(masses)
    com = sum(m * p for m, p in zip(masses, points)) / total
    J = np.zeros((3, 3))
    for m, p in zip(masses, points):
        x, y, z = p - com
        J += m * np.array([[y * y + z * z, -x * y, -x * z],
                           [-x * y, x * x + z * z, -y * z],
                           [-x * z, -y * z, x * x + y * y]])
    return com, J


def test_centre_of_mass_is_the_mass_weighted_mean():
    # 1 kg at x = 0 and 3 kg at x = 4: the COM is at 3 (the slide's Σmx/Σmx would give 1, not a position)
    points = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [2.0, 1.0, 0.0], [2.0, -1.0, 0.0]])
    masses = np.array([1.0, 3.0, 1e-3, 1e-3])
    total, com, _ = particle_mass_properties(points, masses)
    assert total == pytest.approx(4.002)
    assert com == pytest.approx([(0 * 1 + 4 * 3 + 2e-3 + 2e-3) / 4.002, 0.0, 0.0], rel=1e-14, abs=1e-15)


def test_vectorized_tensor_equals_the_lecture_sum_particle_by_particle():
    rng = np.random.default_rng(RNG_SEED)
    points = rng.normal(size=(50, 3)) * [1.0, 0.5, 2.0] + [3.0, -1.0, 0.5]
    masses = rng.uniform(0.1, 2.0, size=50)
    total, com, J = particle_mass_properties(points, masses)
    ref_com, ref_J = lecture_tensor_by_loop(points, masses)
    assert total == pytest.approx(masses.sum(), rel=1e-15)
    np.testing.assert_allclose(com, ref_com, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(J, ref_J, rtol=1e-12, atol=1e-12)


def test_tensor_gives_the_angular_momentum_of_the_spinning_particles():
    """The definition the tensor comes from: L = Σ mᵢ rᵢ × vᵢ with vᵢ = ω × rᵢ equals J ω, for any ω."""
    rng = np.random.default_rng(RNG_SEED + 1)
    points = rng.normal(size=(30, 3))
    masses = rng.uniform(0.5, 1.5, size=30)
    _, com, J = particle_mass_properties(points, masses)
    r = points - com
    for omega in rng.normal(size=(5, 3)):
        v = np.cross(omega, r)
        L = (masses[:, None] * np.cross(r, v)).sum(axis=0)
        np.testing.assert_allclose(J @ omega, L, rtol=1e-12, atol=1e-12)
        # and the rotational kinetic energy ½ Σ mᵢ|vᵢ|² = ½ ωᵀ J ω
        assert 0.5 * omega @ J @ omega == pytest.approx(0.5 * (masses * (v * v).sum(axis=1)).sum(), rel=1e-12)


def test_zz_entry_is_about_the_z_axis():
    # particles on the z axis only: no inertia about z (slide erratum: the slide's zz = Σ m (y² + z²) ≠ 0)
    points = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, -2.0, 0.0]])
    _, _, J = particle_mass_properties(points, np.ones(4))
    np.testing.assert_allclose(J, np.diag([8.0, 2.0, 10.0]), atol=1e-15)  # zz = Σ m (x² + y²)


def test_tensor_rotates_as_R_J_Rt_and_ignores_translation():
    rng = np.random.default_rng(RNG_SEED + 2)
    points = rng.normal(size=(20, 3))
    masses = rng.uniform(0.5, 1.5, size=20)
    _, com, J = particle_mass_properties(points, masses)
    R = quat_to_matrix(quat_from_rotvec(np.array([0.3, -1.2, 0.7])))
    moved = points @ R.T + np.array([10.0, -5.0, 2.0])
    _, com2, J2 = particle_mass_properties(moved, masses)
    np.testing.assert_allclose(com2, R @ com + [10.0, -5.0, 2.0], atol=1e-12)
    np.testing.assert_allclose(J2, R @ J @ R.T, rtol=1e-12, atol=1e-12)


# ---- convergence of particle sets to the closed forms ----------------------------------------------------


def test_box_grid_equals_closed_form_minus_the_cell_term_exactly():
    """On an n³ grid Σ yᵢ² = n² (a²/12)(1 − 1/n²) per column, so J_grid = J_box − m/12 diag(dy²+dz², ...)
    with d = size/n: the error is exactly the cells' own inertia and shrinks like 1/n²."""
    size, mass = np.array([0.1, 0.4, 0.8]), 2.0
    exact = box_inertia(mass, size)
    errors = []
    for n in (2, 4, 8, 16, 32):
        points, masses = box_grid(size, n, mass)
        total, com, J = particle_mass_properties(points, masses)
        d2 = (size / n) ** 2
        cell_term = mass / 12.0 * np.diag([d2[1] + d2[2], d2[0] + d2[2], d2[0] + d2[1]])
        assert total == pytest.approx(mass, rel=1e-14)
        np.testing.assert_allclose(com, 0.0, atol=1e-15)
        np.testing.assert_allclose(J, exact - cell_term, rtol=1e-12, atol=1e-15)
        errors.append(relative_error(J, exact))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    np.testing.assert_allclose(ratios, 4.0, rtol=1e-9)
    assert errors[-1] < 1.0 / 32**2


SOLIDS = {
    # name: (sampler(n) -> points, masses; closed form)
    "sphere": (lambda n: ball_cells(0.3, n, 500.0), solid_sphere_inertia(500.0 * 4 / 3 * math.pi * 0.3**3, 0.3)),
    "cylinder": (
        lambda n: cylinder_cells(0.2, 0.5, n, 500.0),
        cylinder_inertia(500.0 * math.pi * 0.2**2 * 1.0, 0.2, 0.5),
    ),
    "capsule": (
        lambda n: capsule_cells(0.2, 0.5, n, 500.0),
        capsule_inertia(500.0 * (math.pi * 0.2**2 * 1.0 + 4 / 3 * math.pi * 0.2**3), 0.2, 0.5),
    ),
}


@pytest.mark.parametrize("solid", sorted(SOLIDS))
def test_sampled_solid_converges_to_closed_form_like_one_over_n_squared(solid):
    sampler, exact = SOLIDS[solid]
    errors = []
    for n in (4, 8, 16, 32):
        points, masses = sampler(n)
        total, com, J = particle_mass_properties(points, masses)
        np.testing.assert_allclose(com, 0.0, atol=1e-12)  # the samples are symmetric about the centre
        assert J == pytest.approx(J.T, abs=0.0)
        errors.append(relative_error(J, exact))
    errors = np.array(errors)
    ratios = errors[:-1] / errors[1:]
    assert np.all((ratios > 3.5) & (ratios < 4.5)), f"{solid}: errors {errors}, ratios {ratios}"
    assert errors[-1] < 2e-3, f"{solid}: errors {errors}"


def test_capsule_reduces_to_sphere_and_grows_like_a_cylinder():
    np.testing.assert_allclose(capsule_inertia(3.0, 0.2, 0.0), solid_sphere_inertia(3.0, 0.2), rtol=1e-15)
    # a long capsule is a cylinder: the caps' share of mass and moment vanishes like r / half_length
    for r, a in ((0.1, 10.0), (0.01, 100.0)):
        difference = relative_error(capsule_inertia(3.0, r, a), cylinder_inertia(3.0, r, a))
        assert 0.0 < difference < 2.0 * r / a


# ---- parallel axis ---------------------------------------------------------------------------------------


def inertia_about_point_by_loop(points, masses, origin):
    J = np.zeros((3, 3))
    for m, p in zip(masses, points):
        r = p - origin
        J += m * (r @ r * np.eye(3) - np.outer(r, r))
    return J


def test_parallel_axis_matches_particle_sums_about_shifted_origins():
    rng = np.random.default_rng(RNG_SEED + 3)
    points = rng.normal(size=(40, 3)) * [0.5, 1.0, 0.2]
    masses = rng.uniform(0.2, 1.0, size=40)
    total, com, J = particle_mass_properties(points, masses)
    origins = rng.normal(size=(4, 3)) * 3.0
    for origin in origins:
        direct = inertia_about_point_by_loop(points, masses, origin)
        np.testing.assert_allclose(parallel_axis(J, total, com - origin), direct, rtol=1e-12, atol=1e-12)
    # batched: one call for all origins
    batched = parallel_axis(np.broadcast_to(J, (4, 3, 3)), np.full(4, total), com - origins)
    np.testing.assert_allclose(batched[2], inertia_about_point_by_loop(points, masses, origins[2]), rtol=1e-12)


def test_parallel_axis_rod_about_its_end():
    # a thin rod of length 2 about its end: m l² / 3 = 4m/3 (closed form), from m l²/12 + m (l/2)²
    I_end = parallel_axis(cylinder_inertia(1.0, 1e-9, 1.0), 1.0, [0.0, 0.0, 1.0])
    assert I_end[0, 0] == pytest.approx(4.0 / 3.0, rel=1e-12)
    assert I_end[2, 2] == pytest.approx(0.0, abs=1e-15)


# ---- properties every inertia tensor has ----------------------------------------------------------------


def tensors_to_check():
    rng = np.random.default_rng(RNG_SEED + 4)
    out = [
        solid_sphere_inertia(2.0, 0.3),
        box_inertia(2.0, [0.1, 0.4, 0.8]),
        cylinder_inertia(1.0, 0.1, 2.0),
        capsule_inertia(1.0, 0.3, 0.1),
    ]
    for k in (3, 4, 10, 100):
        out.append(particle_mass_properties(rng.normal(size=(k, 3)), rng.uniform(0.1, 1.0, size=k))[2])
    # a planar set: the triangle inequality holds with equality (perpendicular-axis theorem)
    planar = rng.normal(size=(10, 3)) * [1.0, 1.0, 0.0]
    out.append(particle_mass_properties(planar, np.ones(10))[2])
    return out


@pytest.mark.parametrize("index", range(9))
def test_symmetric_positive_definite_triangle_inequality(index):
    J = tensors_to_check()[index]
    assert np.array_equal(J, J.T)
    moments, axes = principal_axes(J)
    assert moments[0] > 0.0
    # I1 + I2 >= I3 for every rigid body (Σ m (a² + b²) + Σ m (a² + c²) >= Σ m (b² + c²))
    assert moments[0] + moments[1] >= moments[2] * (1.0 - 1e-12)
    np.testing.assert_allclose(axes @ np.diag(moments) @ axes.T, J, rtol=1e-12, atol=1e-14 * moments[2])
    np.testing.assert_allclose(axes.T @ axes, np.eye(3), atol=1e-14)
    assert np.linalg.det(axes) == pytest.approx(1.0)


def test_planar_set_obeys_the_perpendicular_axis_theorem():
    J = tensors_to_check()[8]
    assert J[2, 2] == pytest.approx(J[0, 0] + J[1, 1], rel=1e-13)


# ---- shape_mass_properties: what the scene loader calls --------------------------------------------------


def test_density_gives_mass_from_the_volume():
    mass, I = shape_mass_properties("box", size=[0.1, 0.4, 0.8], density=1000.0)
    assert mass == pytest.approx(1000.0 * 0.1 * 0.4 * 0.8)
    np.testing.assert_allclose(I, box_inertia(mass, [0.1, 0.4, 0.8]))
    mass, I = shape_mass_properties("sphere", radius=0.5, density=2.0)
    assert mass == pytest.approx(2.0 * 4.0 / 3.0 * math.pi * 0.125)
    mass, I = shape_mass_properties(Shape.CAPSULE, radius=0.1, half_length=0.3, density=1.0)
    assert mass == pytest.approx(math.pi * 0.01 * 0.6 + 4.0 / 3.0 * math.pi * 0.001)
    mass, I = shape_mass_properties("Cylinder", radius=0.1, half_length=0.3, mass=4.0)
    assert mass == 4.0
    np.testing.assert_allclose(I, cylinder_inertia(4.0, 0.1, 0.3))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(shape="sphere", radius=0.1), "exactly one of mass and density"),
        (dict(shape="sphere", radius=0.1, mass=1.0, density=1.0), "exactly one of mass and density"),
        (dict(shape="sphere", mass=1.0), "sphere needs radius"),
        (dict(shape="box", size=[1, 1, 1], radius=0.1, mass=1.0), "box does not take radius"),
        (dict(shape="box", size=[1, 1], mass=1.0), "3 numbers"),
        (dict(shape="box", size=[1, 0, 1], mass=1.0), "positive"),
        (dict(shape="capsule", radius=0.1, mass=1.0), "capsule needs half_length"),
        (dict(shape="capsule", radius=0.1, half_length=-1.0, mass=1.0), "half_length"),
        (dict(shape="sphere", radius=-0.1, mass=1.0), "radius must be a positive"),
        (dict(shape="sphere", radius=0.1, mass=0.0), "mass must be a positive"),
        (dict(shape="sphere", radius=0.1, density=float("nan")), "density must be a positive"),
        (dict(shape="cone", radius=0.1, mass=1.0), "unknown solid shape 'cone'"),
        (dict(shape="particles", mass=1.0), "particle_mass_properties"),
    ],
)
def test_shape_mass_properties_rejects_bad_input_naming_it(kwargs, message):
    shape = kwargs.pop("shape")
    with pytest.raises(ValueError, match=message):
        shape_mass_properties(shape, **kwargs)


@pytest.mark.parametrize(
    "points, masses, message",
    [
        ([[1.0, 2.0, 3.0]], [1.0], "single particle"),
        ([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]], [1.0, 2.0, 3.0], "collinear"),
        ([[1.0, 1.0, 1.0]] * 3, [1.0, 1.0, 1.0], "same point"),
        ([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [1.0, 0.0, 1.0], "masses must be > 0"),
        ([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [1.0, -2.0, 1.0], "particle.*1"),
        ([[0.0, 0.0], [1.0, 0.0]], [1.0, 1.0], r"shape \(k, 3\)"),
        ([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], [1.0], r"shape \(2,\)"),
        (np.zeros((0, 3)), np.zeros(0), "at least one particle"),
        ([[0.0, 0.0, np.nan], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [1.0, 1.0, 1.0], "finite"),
    ],
)
def test_particle_mass_properties_rejects_degenerate_sets_naming_the_reason(points, masses, message):
    with pytest.raises(ValueError, match=message):
        particle_mass_properties(np.asarray(points, dtype=float), np.asarray(masses, dtype=float))


def test_three_non_collinear_particles_are_a_valid_body():
    total, com, J = particle_mass_properties(np.array([[0.0, 0, 0], [1.0, 0, 0], [0.0, 1, 0]]), np.ones(3))
    assert np.linalg.eigvalsh(J)[0] > 0.0

"""Mass properties of rigid bodies: the lecture's particle-set inertia tensor, closed forms for the solid
shapes, the parallel-axis theorem and principal axes.

This module is the one home of the lecture's equations

    COM   x̄ = Σ mᵢ xᵢ / M,   M = Σ mᵢ
    Jᵢ      = mᵢ [[yᵢ²+zᵢ²,  −xᵢyᵢ,    −xᵢzᵢ  ],
                  [−xᵢyᵢ,    xᵢ²+zᵢ², −yᵢzᵢ  ],      with (xᵢ, yᵢ, zᵢ) = rᵢ = xᵢ − x̄
                  [−xᵢzᵢ,    −yᵢzᵢ,   xᵢ²+yᵢ²]]
    J       = Σ Jᵢ                                    (so that L = J ω about the COM)

All tensors are about the centre of mass, in body axes, in kg m².  Solid shapes are homogeneous; their body
axes are the shape's own axes (box edges; capsule and cylinder axis = body z), so their tensors are diagonal.

Beyond the particles and the closed forms: a homogeneous polyhedron bounded by a closed triangle mesh (a convex
hull, a mesh file), exactly, by the divergence theorem (:func:`polyhedron_mass_properties`: Mirtich 1996,
Eberly's *Polyhedral Mass Properties*; its axes are the mesh's, so its tensor is full in general), and a body
made of parts (:func:`compound_mass_properties`): the lecture's J = Σ Jᵢ with each part's own tensor turned into
the body's axes and moved to the body's COM by the parallel-axis theorem.
"""

from __future__ import annotations

import math

import numpy as np

from .bodies import Shape
from .checks import non_negative, positive

#: A particle set whose smallest principal moment is below this fraction of its largest is rejected as
#: singular.  A rod of point masses has exactly zero inertia about its axis; nearly-collinear sets with
#: ratios beyond 1e10 would make ω = J⁻¹ L meaningless in double precision (and every integrator stiff).
SINGULAR_INERTIA_RTOL = 1e-10


# ---- the lecture's particle set --------------------------------------------------------------------------


def particle_mass_properties(points: np.ndarray, masses: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Total mass, centre of mass and inertia tensor about the COM of a set of point masses.

    Args:
        points: (k, 3) particle positions (any frame; the tensor is returned in that frame's axes).
        masses: (k,) particle masses, all > 0.

    Returns:
        ``(M, com, J)``: ``M`` float, ``com`` (3,), ``J`` (3, 3) = Σ Jᵢ about ``com``.

    Raises:
        ValueError: wrong shapes, non-finite values, non-positive masses, or a set whose tensor is singular
        (a single particle, coincident or collinear particles), naming the reason.
    """
    points = np.asarray(points, dtype=float)
    masses = np.asarray(masses, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"particle positions must have shape (k, 3), got {points.shape}")
    if masses.shape != (len(points),):
        raise ValueError(f"particle masses must have shape ({len(points)},) to match the positions, "
                         f"got {masses.shape}")
    if len(points) == 0:
        raise ValueError("a particle body needs at least one particle (got none)")
    if not (np.isfinite(points).all() and np.isfinite(masses).all()):
        raise ValueError("particle positions and masses must be finite numbers")
    if (masses <= 0.0).any():
        bad = np.flatnonzero(masses <= 0.0)
        raise ValueError(f"particle masses must be > 0; particle(s) {', '.join(map(str, bad[:5]))} "
                         f"have {', '.join(f'{m:g}' for m in masses[bad[:5]])}")
    if len(points) == 1:
        raise ValueError("a single particle has no rotational inertia about its own centre of mass "
                         "(singular inertia tensor): a rigid particle body needs at least 3 non-collinear "
                         "particles")

    total_mass = float(masses.sum())
    # Slide erratum ("Center of mass" slide): the slide writes x̄ = Σ mᵢxᵢ / Σ mᵢxᵢ, which is not even a
    # length; the centre of mass is the mass-weighted mean x̄ = Σ mᵢxᵢ / M with M = Σ mᵢ.
    com = masses @ points / total_mass
    r = points - com  # rᵢ = xᵢ − x̄, the lecture's (xᵢ, yᵢ, zᵢ)

    # J = Σ Jᵢ, entry by entry: the sums Σ mᵢ xᵢ yᵢ etc. are the second moments of the mass distribution.
    second = np.einsum("k,ki,kj->ij", masses, r, r)  # S[a, b] = Σ mᵢ rᵢ[a] rᵢ[b]
    xx, yy, zz = second[0, 0], second[1, 1], second[2, 2]
    xy, xz, yz = second[0, 1], second[0, 2], second[1, 2]
    # Slide erratum ("Moment of Inertia in 3D"): the slide's last diagonal entry is yᵢ² + zᵢ² (a copy of the
    # first); the moment about the z axis involves the distances from that axis, xᵢ² + yᵢ².
    inertia = np.array(
        [
            [yy + zz, -xy, -xz],
            [-xy, xx + zz, -yz],
            [-xz, -yz, xx + yy],
        ]
    )
    moments = np.linalg.eigvalsh(inertia)
    if moments[0] <= SINGULAR_INERTIA_RTOL * moments[2]:
        if moments[2] <= 0.0:
            reason = "all particles are at the same point"
        else:
            reason = "the particles are (nearly) collinear, so the body has no inertia about that line"
        raise ValueError(
            f"singular inertia tensor: {reason} (principal moments {moments[0]:.3g}, {moments[1]:.3g}, "
            f"{moments[2]:.3g} kg m²); a rigid particle body needs at least 3 non-collinear particles"
        )
    return total_mass, com, inertia


# ---- closed forms (homogeneous solids, about the COM, shape axes) ----------------------------------------


def _extents(size) -> np.ndarray:
    try:
        size = np.asarray(size, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"box size must be 3 numbers [x, y, z], got {size!r}") from None
    if size.shape != (3,):
        raise ValueError(f"box size must be 3 numbers [x, y, z] (full extents), got shape {size.shape}")
    if not (np.isfinite(size).all() and (size > 0.0).all()):
        raise ValueError(f"box size must be 3 positive finite numbers (full extents), got {size.tolist()}")
    return size


def solid_sphere_inertia(mass: float, radius: float) -> np.ndarray:
    """(3, 3): I = (2/5) m r² on the diagonal."""
    mass, radius = positive(mass, "mass"), positive(radius, "radius")
    return np.eye(3) * (0.4 * mass * radius * radius)


def box_inertia(mass: float, size) -> np.ndarray:
    """(3, 3): a solid box with full extents ``size = (a, b, c)`` along body x, y, z:
    I = m/12 · diag(b² + c², a² + c², a² + b²)."""
    mass = positive(mass, "mass")
    a2, b2, c2 = _extents(size) ** 2
    return np.diag([b2 + c2, a2 + c2, a2 + b2]) * (mass / 12.0)


def cylinder_inertia(mass: float, radius: float, half_length: float) -> np.ndarray:
    """(3, 3): a solid cylinder of ``radius``, axis = body z, length ``2 half_length``:
    I_zz = m r² / 2,  I_xx = I_yy = m (3 r² + (2 half_length)²) / 12."""
    mass, radius = positive(mass, "mass"), positive(radius, "radius")
    length = 2.0 * positive(half_length, "half_length")
    across = mass * (3.0 * radius * radius + length * length) / 12.0
    return np.diag([across, across, 0.5 * mass * radius * radius])


def capsule_inertia(mass: float, radius: float, half_length: float) -> np.ndarray:
    """(3, 3): a solid capsule — a cylinder of length ``2 half_length`` along body z capped by two
    hemispheres of ``radius`` — the body swept by a sphere along the segment [−half_length, half_length] ẑ.

    The mass splits between cylinder and caps by volume.  Each hemisphere (mass m_h, COM 3r/8 from its flat
    face) has, about the diameter in its flat face, the same moment as a full sphere, (2/5) m_h r², hence
    about its own COM (2/5 − 9/64) m_h r², and about the capsule's centre (distance a + 3r/8, a = half_length):
    m_h [(2/5) r² + a² + (3/4) a r] by the parallel-axis theorem.
    """
    mass, radius = positive(mass, "mass"), positive(radius, "radius")
    a = non_negative(half_length, "half_length")
    r2 = radius * radius
    cylinder_volume = math.pi * r2 * 2.0 * a
    caps_volume = 4.0 / 3.0 * math.pi * r2 * radius
    m_cyl = mass * cylinder_volume / (cylinder_volume + caps_volume)
    m_caps = mass - m_cyl  # both hemispheres together
    axial = 0.5 * m_cyl * r2 + 0.4 * m_caps * r2
    across = m_cyl * (3.0 * r2 + 4.0 * a * a) / 12.0 + m_caps * (0.4 * r2 + a * a + 0.75 * a * radius)
    return np.diag([across, across, axial])


def parallel_axis(inertia_com: np.ndarray, mass, offset: np.ndarray) -> np.ndarray:
    """Inertia about a point displaced by ``offset`` from the COM (same axes): I + m (|d|² 1 − d dᵀ).

    Broadcasts: ``inertia_com`` (..., 3, 3), ``mass`` scalar or (...,), ``offset`` (..., 3).
    """
    inertia_com = np.asarray(inertia_com, dtype=float)
    d = np.asarray(offset, dtype=float)
    mass = np.asarray(mass, dtype=float)[..., None, None]
    d_dot_d = np.einsum("...i,...i->...", d, d)[..., None, None]
    return inertia_com + mass * (d_dot_d * np.eye(3) - d[..., :, None] * d[..., None, :])


def principal_axes(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments (ascending) and axes of a symmetric inertia tensor.

    Returns ``(moments (..., 3), axes (..., 3, 3))`` with the axes as the columns of a proper rotation
    (det = +1), so ``inertia == axes @ diag(moments) @ axes.T``.
    """
    inertia = np.asarray(inertia, dtype=float)
    if inertia.shape[-2:] != (3, 3):
        raise ValueError(f"inertia tensor must have shape (..., 3, 3), got {inertia.shape}")
    scale = np.abs(inertia).max(axis=(-2, -1), keepdims=True)
    if not np.all(np.abs(inertia - np.swapaxes(inertia, -1, -2)) <= 1e-9 * scale):
        raise ValueError("inertia tensor must be symmetric")
    moments, axes = np.linalg.eigh(inertia)
    # eigh may return a reflection; flipping the last axis keeps the basis right-handed.
    axes[..., :, 2] *= np.sign(np.linalg.det(axes))[..., None]
    return moments, axes


# ---- what the scene loader calls -------------------------------------------------------------------------


def sphere_volume(radius: float) -> float:
    return 4.0 / 3.0 * math.pi * radius**3


def box_volume(size) -> float:
    return float(np.prod(size))


def cylinder_volume(radius: float, half_length: float) -> float:
    return math.pi * radius * radius * 2.0 * half_length


def capsule_volume(radius: float, half_length: float) -> float:
    return cylinder_volume(radius, half_length) + sphere_volume(radius)


# which parameters each solid shape takes (the others must be left None)
_SHAPE_PARAMETERS = {
    "sphere": ("radius",),
    "box": ("size",),
    "capsule": ("radius", "half_length"),
    "cylinder": ("radius", "half_length"),
}


def shape_mass_properties(shape, *, radius=None, size=None, half_length=None, mass=None,
                          density=None) -> tuple[float, np.ndarray]:
    """Mass and body inertia tensor (3, 3) of a homogeneous solid.

    Args:
        shape: ``"sphere"``, ``"box"``, ``"capsule"``, ``"cylinder"`` (case-insensitive) or a
            :class:`~cgp_core.bodies.Shape` (SPHERE, BOX, CAPSULE).  Particle bodies use
            :func:`particle_mass_properties`.
        radius: sphere / capsule / cylinder radius [m].
        size: box full extents (3,) [m].
        half_length: capsule / cylinder half length of the axis segment (without the caps) [m].
        mass: total mass [kg] — give exactly one of ``mass`` and ``density``.
        density: [kg/m³]; the mass is density × volume.

    Raises:
        ValueError naming the shape and the missing, superfluous or invalid parameter.
    """
    name = shape.name.lower() if isinstance(shape, Shape) else str(shape).lower()
    if name not in _SHAPE_PARAMETERS:
        hint = " (use particle_mass_properties)" if name == "particles" else ""
        raise ValueError(f"unknown solid shape {shape!r}{hint}; valid: {', '.join(_SHAPE_PARAMETERS)}")
    given = {"radius": radius, "size": size, "half_length": half_length}
    for key, value in given.items():
        if key in _SHAPE_PARAMETERS[name] and value is None:
            raise ValueError(f"{name} needs {key}")
        if key not in _SHAPE_PARAMETERS[name] and value is not None:
            raise ValueError(f"{name} does not take {key} (it takes {', '.join(_SHAPE_PARAMETERS[name])})")
    if (mass is None) == (density is None):
        raise ValueError(f"{name}: give exactly one of mass and density")

    if name == "sphere":
        volume = sphere_volume(positive(radius, "radius"))
    elif name == "box":
        volume = box_volume(_extents(size))
    elif name == "capsule":
        volume = capsule_volume(positive(radius, "radius"), non_negative(half_length, "half_length"))
    else:
        volume = cylinder_volume(positive(radius, "radius"), positive(half_length, "half_length"))
    body_mass = positive(mass, "mass") if mass is not None else positive(density, "density") * volume

    if name == "sphere":
        return body_mass, solid_sphere_inertia(body_mass, radius)
    if name == "box":
        return body_mass, box_inertia(body_mass, size)
    if name == "capsule":
        return body_mass, capsule_inertia(body_mass, radius, half_length)
    return body_mass, cylinder_inertia(body_mass, radius, half_length)


# ---- polyhedra (closed triangle meshes): Mirtich 1996 / Eberly, "Polyhedral Mass Properties" -------------

class MeshMassError(ValueError):
    """A triangle mesh whose mass properties are undefined (open, inverted, degenerate); names why."""


def closed_surface_problem(triangles: np.ndarray) -> str | None:
    """Why ``triangles (t, 3)`` is not a closed, consistently oriented surface, or None.  Closed and oriented:
    every directed edge (u, v) occurs exactly once and its reverse (v, u) exactly once."""
    if len(triangles) < 4:
        return f"a closed surface needs at least 4 triangles, got {len(triangles)}"
    if (triangles[:, 0] == triangles[:, 1]).any() or (triangles[:, 1] == triangles[:, 2]).any() \
            or (triangles[:, 0] == triangles[:, 2]).any():
        return "a triangle repeats a vertex"
    directed = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    key = directed[:, 0].astype(np.int64) * (int(directed.max()) + 1) + directed[:, 1]
    unique, counts = np.unique(key, return_counts=True)
    if (counts > 1).any():
        return "an edge is used twice in the same direction (triangles oriented inconsistently, or non-manifold)"
    reverse = directed[:, 1].astype(np.int64) * (int(directed.max()) + 1) + directed[:, 0]
    if not np.isin(reverse, unique).all():
        return f"{int((~np.isin(reverse, unique)).sum())} edge(s) border only one triangle (the mesh has holes)"
    return None


def polyhedron_mass_properties(vertices, triangles, *, mass=None, density=None,
                               what: str = "mesh") -> tuple[float, np.ndarray, np.ndarray, float]:
    """Mass, centre of mass, inertia tensor about the COM and volume of a homogeneous solid bounded by a closed
    triangle mesh, exactly, by the divergence theorem (Mirtich 1996; Eberly, *Game Physics*, "Polyhedral Mass
    Properties"): each volume integral ∫ 1, ∫ x, ∫ x², ∫ xy ... over the solid becomes a sum over the
    triangles of a surface integral, which is a polynomial in the triangle's vertex coordinates.

    Args:
        vertices: (V, 3) positions.
        triangles: (T, 3) vertex indices, counter-clockwise seen from outside (outward normals).
        mass, density: give exactly one (kg, kg/m³).
        what: names the mesh in errors.

    Returns:
        ``(mass, com (3,), inertia (3, 3) about the COM in the mesh's axes, volume)``.

    Raises:
        MeshMassError: the mesh is not closed and consistently oriented, or is inverted (negative volume:
        normals inward), or has no volume.
    """
    vertices = np.asarray(vertices, dtype=float)
    triangles = np.asarray(triangles)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or triangles.ndim != 2 or triangles.shape[1] != 3:
        raise MeshMassError(f"{what}: vertices must be (V, 3) and triangles (T, 3), got {vertices.shape} and "
                            f"{triangles.shape}")
    if not np.isfinite(vertices).all():
        raise MeshMassError(f"{what}: vertex coordinates must be finite numbers")
    if len(triangles) and (triangles.min() < 0 or triangles.max() >= len(vertices)):
        raise MeshMassError(f"{what}: a triangle indexes a vertex that does not exist")
    if (mass is None) == (density is None):
        raise MeshMassError(f"{what}: give exactly one of mass and density")
    problem = closed_surface_problem(triangles)
    if problem:
        raise MeshMassError(f"{what}: not a closed surface, so it bounds no solid: {problem}")
    # About a reference point inside the vertices' bounding box, not the file's origin: the second moments
    # about a far origin would cancel catastrophically in the parallel-axis shift to the COM.
    reference = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    p = vertices - reference
    x0, x1, x2 = (p[triangles[:, k]] for k in range(3))
    # d = (p1 − p0) × (p2 − p0): twice the area times the outward normal
    d = np.cross(x1 - x0, x2 - x0)
    # Eberly's subexpressions per coordinate w (columns x, y, z): f1 = Σw, f2 = Σ w², f3 = Σ w³ over the
    # triangle's polynomial basis, g_i = f2 + w_i (f1 + w_i)
    w0, w1, w2 = x0, x1, x2
    temp0 = w0 + w1
    f1 = temp0 + w2
    temp1 = w0 * w0
    temp2 = temp1 + w1 * temp0
    f2 = temp2 + w2 * f1
    f3 = w0 * temp1 + w1 * temp2 + w2 * f2
    g0 = f2 + w0 * (f1 + w0)
    g1 = f2 + w1 * (f1 + w1)
    g2 = f2 + w2 * (f1 + w2)
    X, Y, Z = 0, 1, 2
    volume = float(np.sum(d[:, X] * f1[:, X])) / 6.0                        # ∫ 1
    first = np.array([np.sum(d[:, X] * f2[:, X]), np.sum(d[:, Y] * f2[:, Y]),
                      np.sum(d[:, Z] * f2[:, Z])]) / 24.0                     # ∫ x, ∫ y, ∫ z
    square = np.array([np.sum(d[:, X] * f3[:, X]), np.sum(d[:, Y] * f3[:, Y]),
                       np.sum(d[:, Z] * f3[:, Z])]) / 60.0                    # ∫ x², ∫ y², ∫ z²
    xy = np.sum(d[:, X] * (w0[:, Y] * g0[:, X] + w1[:, Y] * g1[:, X] + w2[:, Y] * g2[:, X])) / 120.0
    yz = np.sum(d[:, Y] * (w0[:, Z] * g0[:, Y] + w1[:, Z] * g1[:, Y] + w2[:, Z] * g2[:, Y])) / 120.0
    zx = np.sum(d[:, Z] * (w0[:, X] * g0[:, Z] + w1[:, X] * g1[:, Z] + w2[:, X] * g2[:, Z])) / 120.0
    extent = float(np.max(vertices.max(axis=0) - vertices.min(axis=0)))
    if volume < 0.0 and abs(volume) > 1e-12 * extent**3:
        raise MeshMassError(f"{what}: the mesh is inverted (its triangles face inward: volume {volume:.6g} m³ < 0); "
                            "reverse the triangles' vertex order")
    if volume <= 1e-12 * extent**3:
        raise MeshMassError(f"{what}: the closed surface encloses no volume ({volume:.3g} m³)")
    com_local = first / volume
    body_mass = positive(mass, "mass") if mass is not None else positive(density, "density") * volume
    rho = body_mass / volume
    # second moments about the COM (per unit density): ∫ x² − V c_x² ...
    sxx = square[0] - volume * com_local[0] ** 2
    syy = square[1] - volume * com_local[1] ** 2
    szz = square[2] - volume * com_local[2] ** 2
    sxy = xy - volume * com_local[0] * com_local[1]
    syz = yz - volume * com_local[1] * com_local[2]
    szx = zx - volume * com_local[2] * com_local[0]
    inertia = rho * np.array([[syy + szz, -sxy, -szx],
                              [-sxy, sxx + szz, -syz],
                              [-szx, -syz, sxx + syy]])
    return body_mass, com_local + reference, inertia, volume


# ---- compound bodies: J = Σ Jᵢ generalised from particles to parts ------------------------------------------

def compound_mass_properties(masses, coms, rotations, inertias) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, COM and inertia tensor about the COM of a rigid body made of ``k`` parts.

    The lecture's J = Σ Jᵢ for point masses, generalised to parts with their own inertia: part i (mass mᵢ, COM
    xᵢ, inertia Jᵢ about its own COM in its own axes, axes turned by Rᵢ relative to the body's) contributes its
    own tensor turned into the body's axes, Rᵢ Jᵢ Rᵢᵀ, plus the particle term of its mass at its COM, mᵢ (|dᵢ|² 1
    − dᵢ dᵢᵀ) with dᵢ = xᵢ − x̄ (the parallel-axis theorem, :func:`parallel_axis`):

        M = Σ mᵢ,   x̄ = Σ mᵢ xᵢ / M,   J = Σ (Rᵢ Jᵢ Rᵢᵀ + mᵢ (|dᵢ|² 1 − dᵢ dᵢᵀ)).

    Args:
        masses: (k,) part masses > 0.
        coms: (k, 3) part COMs in the body's reference frame.
        rotations: (k, 3, 3) part axes in the body's axes (columns).
        inertias: (k, 3, 3) part inertia tensors about their COMs in their own axes (e.g. from
            :func:`shape_mass_properties` or :func:`polyhedron_mass_properties`).

    Returns:
        ``(M, com (3,), J (3, 3))``.
    """
    masses = np.asarray(masses, dtype=float)
    coms = np.asarray(coms, dtype=float)
    rotations = np.asarray(rotations, dtype=float)
    inertias = np.asarray(inertias, dtype=float)
    k = len(masses)
    if k == 0:
        raise ValueError("a compound body needs at least one part")
    if masses.shape != (k,) or coms.shape != (k, 3) or rotations.shape != (k, 3, 3) or inertias.shape != (k, 3, 3):
        raise ValueError(f"compound parts: masses (k,), coms (k, 3), rotations and inertias (k, 3, 3) with the same "
                         f"k; got {masses.shape}, {coms.shape}, {rotations.shape}, {inertias.shape}")
    if not (np.isfinite(masses).all() and np.isfinite(coms).all() and np.isfinite(rotations).all()
            and np.isfinite(inertias).all()):
        raise ValueError("compound parts: masses, COMs, rotations and inertias must be finite numbers")
    if (masses <= 0.0).any():
        raise ValueError(f"compound parts: every part's mass must be > 0, part {int(np.argmax(masses <= 0.0))} has "
                         f"{masses[masses <= 0.0][0]:g}")
    total = float(masses.sum())
    com = masses @ coms / total
    turned = rotations @ inertias @ np.swapaxes(rotations, -1, -2)
    inertia = parallel_axis(turned, masses, coms - com).sum(axis=0)
    return total, com, 0.5 * (inertia + inertia.T)

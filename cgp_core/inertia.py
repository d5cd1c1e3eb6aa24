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

"""Couzin's zonal model: the second rule set of a flock (``rules: couzin``).

Couzin, Krause, James, Ruxton & Franks 2002, "Collective memory and spatial sorting in animal groups",
J. theor. Biol. 218:1-11.  Each animal i has a position c_i, a unit heading v̂_i and the constant speed s.
Per step it looks at its neighbours j (offset r_ij = c_j − c_i, r̂_ij its direction, d = |r_ij|) in three
non-overlapping zones, ignoring those in its *blind volume* (the cone of 360° − α behind it: j is perceived
when the angle between v̂_i and r̂_ij is at most α/2):

- repulsion, d < r_r:                          d_r = −Σ r̂_ij                       (absolute priority)
- orientation, r_r <= d < r_r + Δr_o:         d_o = Σ v̂_j
- attraction, r_r + Δr_o <= d <= r_r + Δr_o + Δr_a:   d_a = Σ r̂_ij

The desired direction d_i is d_r if any neighbour is in the zone of repulsion; otherwise d_o alone, d_a alone,
or ½ (d_o + d_a) when both zones hold neighbours; with no neighbour at all (or a zero sum) the animal keeps
its heading.  d_i is then rotated by a Gaussian random angle of standard deviation σ (about a uniformly random
axis perpendicular to it), and the heading turns towards it by at most θ·dt (it snaps to it when closer);
the animal moves ``c += s v̂ dt``.  All animals update synchronously from the state at the start of the step.

Where the paper leaves a choice, this is the one made (and why):

- ½ (d_o + d_a) averages the two *unit* directions d̂_o, d̂_a: the paper treats desired directions as
  directions (only the direction of d_i matters for the turn), and averaging the raw sums would let the zone
  holding more neighbours win by headcount alone.
- The focal animal is not in its own zone of orientation (its distance 0 is not >= r_r); its own heading
  enters only through the turning-rate limit.
- The blind volume applies to every zone, repulsion included (the paper: neighbours there "cannot be
  detected").
- Coincident animals (d = 0) have no direction r̂_ij: they are ignored by each other (measure zero).
- Noise is a rotational diffusion: σ is the standard deviation per paper step τ = 0.1 s
  (:data:`NOISE_TIME_STEP`), so a tick of dt draws an angle of s.d. σ·sqrt(dt / τ).  The paper steps at τ;
  with this scaling the heading's random walk per second is the same at any tick rate (``rate_hz``), and at
  dt = τ it is exactly the paper's.  θ and s are per second already.

The kernel reads what a neighbour search yields (:class:`NeighborPairs`: slot pairs i < j with float32 offsets
and squared distances; all pairs within r_r + Δr_o + Δr_a), so it runs on the grid, the KD-tree or all pairs.
In topological mode (``topological.py``) the pair weights say which ends count each other, and the zone of
attraction has no outer edge for the k nearest.  Avoidance (walls, bodies, predators: the flock's "needed"
acceleration) takes over the desired direction in proportion to its strength (:func:`blend_avoidance`).

The loops are compiled with numba (``cgp_core.jit``) and read like the paper; under ``NUMBA_DISABLE_JIT=1``
they run as plain Python with the same results.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import njit
from .neighbors import NeighborPairs

#: the paper's time step τ [s] (the response latency of a fish): σ is the noise per τ
NOISE_TIME_STEP = 0.1
#: seed stream of a Couzin flock's noise (its initial state uses the seed itself)
NOISE_STREAM = 2002

# rows of the zone sums, (12, W)
_N_R, _D_R, _N_O, _D_O, _N_A, _D_A = 0, 1, 4, 5, 8, 9


@njit
def zone_sums(i, j, rows, headings, repulsion_radius, orientation_radius, attraction_radius, cos_half_fov,
              counts_forward, counts_backward):
    """Sums over each slot's perceived neighbours, zone by zone.

    Args:
        i, j:               (P,) int32 — slots of the pairs' ends (i < j).
        rows:               (P, 4) float32 — ``[dx, dy, dz, r2]``: offset x_j − x_i and its squared length.
        headings:           (3, W) float64 — unit headings v̂ of the W slots.
        repulsion_radius:   r_r [m].
        orientation_radius: r_r + Δr_o [m].
        attraction_radius:  r_r + Δr_o + Δr_a [m] (inf: no outer edge, topological mode).
        cos_half_fov:       cos(α / 2); <= −1 means no blind volume.
        counts_forward:     (P,) float32 — 1 where i takes j into account, else 0 (topological selection).
        counts_backward:    (P,) float32 — 1 where j takes i into account.

    Returns:
        (12, W) float64: rows n_r, d_r (3), n_o, d_o (3), n_a, d_a (3) (see the module docstring).
    """
    width = headings.shape[1]
    sums = np.zeros((12, width))
    see_all = cos_half_fov <= -1.0
    for p in range(len(i)):
        # widen the float32 offsets first, the same way compiled and as plain Python (there float32 / float
        # would stay float32, NEP 50; compiled, float() of a float32 stays float32)
        r2 = np.float64(rows[p, 3])
        if r2 <= 0.0:
            continue  # coincident: no direction to respond to
        r = math.sqrt(r2)
        ux = np.float64(rows[p, 0]) / r
        uy = np.float64(rows[p, 1]) / r
        uz = np.float64(rows[p, 2]) / r  # r̂_ij, from i to j
        a = i[p]
        b = j[p]
        # i perceives j: j inside i's field of perception (angle(v̂_i, r̂_ij) <= α/2)
        if counts_forward[p] > 0.0 and (see_all or headings[0, a] * ux + headings[1, a] * uy
                                        + headings[2, a] * uz >= cos_half_fov):
            if r < repulsion_radius:
                sums[_N_R, a] += 1.0
                sums[_D_R, a] -= ux
                sums[_D_R + 1, a] -= uy
                sums[_D_R + 2, a] -= uz
            elif r < orientation_radius:
                sums[_N_O, a] += 1.0
                sums[_D_O, a] += headings[0, b]
                sums[_D_O + 1, a] += headings[1, b]
                sums[_D_O + 2, a] += headings[2, b]
            elif r <= attraction_radius:
                sums[_N_A, a] += 1.0
                sums[_D_A, a] += ux
                sums[_D_A + 1, a] += uy
                sums[_D_A + 2, a] += uz
        # j perceives i: r̂_ji = −r̂_ij
        if counts_backward[p] > 0.0 and (see_all or -(headings[0, b] * ux + headings[1, b] * uy
                                                       + headings[2, b] * uz) >= cos_half_fov):
            if r < repulsion_radius:
                sums[_N_R, b] += 1.0
                sums[_D_R, b] += ux
                sums[_D_R + 1, b] += uy
                sums[_D_R + 2, b] += uz
            elif r < orientation_radius:
                sums[_N_O, b] += 1.0
                sums[_D_O, b] += headings[0, a]
                sums[_D_O + 1, b] += headings[1, a]
                sums[_D_O + 2, b] += headings[2, a]
            elif r <= attraction_radius:
                sums[_N_A, b] += 1.0
                sums[_D_A, b] -= ux
                sums[_D_A + 1, b] -= uy
                sums[_D_A + 2, b] -= uz
    return sums


@njit
def desired_directions(sums, headings):
    """The paper's decision rule per animal: d_r if n_r > 0, else d_o, d_a or ½ (d̂_o + d̂_a); the current
    heading when nothing is perceived or the sum vanishes.  ``sums (12, N)``, ``headings (3, N)`` (unit);
    returns unit desired directions (3, N)."""
    n = headings.shape[1]
    out = np.empty((3, n))
    for b in range(n):
        dx = 0.0
        dy = 0.0
        dz = 0.0
        if sums[_N_R, b] > 0.0:
            dx = sums[_D_R, b]
            dy = sums[_D_R + 1, b]
            dz = sums[_D_R + 2, b]
        else:
            count = 0
            if sums[_N_O, b] > 0.0:
                length = math.sqrt(sums[_D_O, b] ** 2 + sums[_D_O + 1, b] ** 2 + sums[_D_O + 2, b] ** 2)
                if length > 0.0:
                    dx += sums[_D_O, b] / length
                    dy += sums[_D_O + 1, b] / length
                    dz += sums[_D_O + 2, b] / length
                count += 1
            if sums[_N_A, b] > 0.0:
                length = math.sqrt(sums[_D_A, b] ** 2 + sums[_D_A + 1, b] ** 2 + sums[_D_A + 2, b] ** 2)
                if length > 0.0:
                    dx += sums[_D_A, b] / length
                    dy += sums[_D_A + 1, b] / length
                    dz += sums[_D_A + 2, b] / length
                count += 1
            if count == 2:
                dx *= 0.5
                dy *= 0.5
                dz *= 0.5
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        if length > 1e-12:
            out[0, b] = dx / length
            out[1, b] = dy / length
            out[2, b] = dz / length
        else:  # nothing perceived, or the responses cancel: carry on
            out[0, b] = headings[0, b]
            out[1, b] = headings[1, b]
            out[2, b] = headings[2, b]
    return out


@njit
def _perpendicular(x, y, z):
    """A unit vector perpendicular to the unit vector (x, y, z) (deterministic: crossed with the world axis it
    is least aligned with)."""
    ax = abs(x)
    ay = abs(y)
    az = abs(z)
    if ax <= ay and ax <= az:  # e_x × v
        px, py, pz = 0.0, -z, y
    elif ay <= az:  # e_y × v
        px, py, pz = z, 0.0, -x
    else:  # e_z × v
        px, py, pz = -y, x, 0.0
    length = math.sqrt(px * px + py * py + pz * pz)
    return px / length, py / length, pz / length


@njit
def turn_headings(headings, desired, noise_angle, noise_azimuth, max_turn):
    """Rotate each desired direction by its noise, then turn each heading towards it by at most ``max_turn``.

    Args:
        headings:      (3, N) unit headings v̂(t).
        desired:       (3, N) unit desired directions d(t + dt).
        noise_angle:   (N,) — the Gaussian angle ψ [rad] by which d is rotated.
        noise_azimuth: (N,) — uniform in [0, 2π): which perpendicular of d it is rotated towards.
        max_turn:      θ·dt [rad].

    Returns:
        (3, N) new unit headings v̂(t + dt).
    """
    n = headings.shape[1]
    out = np.empty((3, n))
    cos_max = math.cos(max_turn)
    sin_max = math.sin(max_turn)
    for b in range(n):
        dx = desired[0, b]
        dy = desired[1, b]
        dz = desired[2, b]
        psi = noise_angle[b]
        if psi != 0.0:
            # d' = cos ψ d + sin ψ (cos φ e1 + sin φ e2), (e1, e2) an orthonormal basis of the plane ⊥ d
            e1x, e1y, e1z = _perpendicular(dx, dy, dz)
            e2x = dy * e1z - dz * e1y
            e2y = dz * e1x - dx * e1z
            e2z = dx * e1y - dy * e1x
            c = math.cos(noise_azimuth[b])
            s = math.sin(noise_azimuth[b])
            cp = math.cos(psi)
            sp = math.sin(psi)
            dx = cp * dx + sp * (c * e1x + s * e2x)
            dy = cp * dy + sp * (c * e1y + s * e2y)
            dz = cp * dz + sp * (c * e1z + s * e2z)
            length = math.sqrt(dx * dx + dy * dy + dz * dz)
            dx /= length
            dy /= length
            dz /= length
        hx = headings[0, b]
        hy = headings[1, b]
        hz = headings[2, b]
        cosine = hx * dx + hy * dy + hz * dz
        if cosine >= cos_max:  # within θ·dt: take the desired direction
            out[0, b] = dx
            out[1, b] = dy
            out[2, b] = dz
            continue
        # turn by θ·dt in the plane of v̂ and d: v̂' = cos θdt v̂ + sin θdt ŵ, ŵ = unit(d − (v̂·d) v̂)
        wx = dx - cosine * hx
        wy = dy - cosine * hy
        wz = dz - cosine * hz
        length = math.sqrt(wx * wx + wy * wy + wz * wz)
        if length < 1e-12:  # d exactly behind: any perpendicular plane will do
            wx, wy, wz = _perpendicular(hx, hy, hz)
        else:
            wx /= length
            wy /= length
            wz /= length
        nx = cos_max * hx + sin_max * wx
        ny = cos_max * hy + sin_max * wy
        nz = cos_max * hz + sin_max * wz
        length = math.sqrt(nx * nx + ny * ny + nz * nz)
        out[0, b] = nx / length
        out[1, b] = ny / length
        out[2, b] = nz / length
    return out


def blend_avoidance(desired: np.ndarray, needed: np.ndarray, full_strength: float) -> np.ndarray:
    """Avoidance takes over the desired direction in proportion to its strength, as Reynolds' prioritized
    allocation does in ``flock.py``: ``d = unit((1 − w) d + w n̂)`` with ``n̂`` the direction of the needed
    acceleration (walls, bodies, predators; (3, N)) and ``w = min(1, |needed| / full_strength)``: 0 where
    nothing is near, 1 (pure avoidance: absolute priority) at ``full_strength``.  Returns (3, N) unit."""
    strength = np.sqrt(np.einsum("ij,ij->j", needed, needed))
    active = strength > 0.0
    if not np.any(active):
        return desired
    out = desired.copy()
    weight = np.minimum(strength[active] / full_strength, 1.0)
    mixed = (1.0 - weight) * desired[:, active] + weight * (needed[:, active] / strength[active])
    length = np.sqrt(np.einsum("ij,ij->j", mixed, mixed))
    keep = length > 1e-12  # exactly opposed halves: keep the social direction
    mixed[:, keep] /= length[keep]
    mixed[:, ~keep] = desired[:, active][:, ~keep]
    out[:, active] = mixed
    return out


def social_directions(pairs: NeighborPairs, point_boid: np.ndarray, headings: np.ndarray, count: int,
                      params, pair_weights: tuple[np.ndarray, np.ndarray] | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The zonal decision for every boid from a neighbour search's pairs.

    Args:
        pairs:        neighbour pairs of the W work slots (within r_r + Δr_o + Δr_a; see ``neighbors.py``).
        point_boid:   (W,) — the boid each work point is (ghost images of a periodic box map to their boid).
        headings:     (3, N) float64 unit headings of the N boids.
        count:        N.
        params:       the flock's :class:`FlockParams` (its ``couzin`` block, ``neighbor_mode``).
        pair_weights: (forward, backward) (P,) float32 each, or None (metric: everyone within range counts).

    Returns:
        ``(desired (3, N) unit, perceived (N,))``: the desired directions and the number of neighbours each
        boid perceived (all zones).
    """
    c = params.couzin
    slot_boid = np.take(point_boid, pairs.order)
    slot_headings = np.ascontiguousarray(headings[:, slot_boid])
    if pair_weights is None:
        ones = np.ones(pairs.count, dtype=np.float32)
        pair_weights = (ones, ones)
    attraction = math.inf if params.neighbor_mode == "topological" else c.perception_radius
    cos_half_fov = math.cos(math.radians(0.5 * c.field_of_view_deg)) if c.field_of_view_deg < 360.0 else -2.0
    sums = zone_sums(pairs.i, pairs.j, pairs.rows, slot_headings, c.repulsion_radius,
                     c.repulsion_radius + c.orientation_width, attraction, cos_half_fov,
                     pair_weights[0], pair_weights[1])
    real = pairs.order < count  # ghosts' sums are dropped: the boid they copy has its own slot
    boid_sums = np.empty((12, count))
    boid_sums[:, pairs.order[real]] = sums[:, real]
    desired = desired_directions(boid_sums, np.ascontiguousarray(headings))
    return desired, boid_sums[_N_R] + boid_sums[_N_O] + boid_sums[_N_A]


def noise_angles(rng: np.random.Generator, count: int, sigma: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The per-tick noise: Gaussian angles of s.d. ``σ·sqrt(dt / τ)`` and uniform azimuths, (N,) each (both are
    drawn even when σ = 0, so a flock's random stream does not depend on σ)."""
    angle = rng.standard_normal(count) * (sigma * math.sqrt(dt / NOISE_TIME_STEP))
    azimuth = rng.random(count) * (2.0 * math.pi)
    return angle, azimuth


def couzin_headings(flock, desired: np.ndarray, needed: np.ndarray, dt: float) -> np.ndarray:
    """Stage 4 of a Couzin flock: blend in avoidance, add the noise, turn by at most θ·dt.  Returns the new
    unit headings (3, N); the caller sets ``v = s v̂``."""
    p = flock.params
    c = p.couzin
    desired = blend_avoidance(desired, needed, p.max_acceleration)
    angle, azimuth = noise_angles(flock._noise, p.count, c.noise, dt)
    return turn_headings(np.ascontiguousarray(flock._heading), desired, angle, azimuth,
                         math.radians(c.turning_rate_deg) * dt)
